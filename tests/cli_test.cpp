// End-to-end tests of the specula command-line tool: exit codes, messages, output files.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "specula/image.h"
#include "test_util.h"
#include "cli_test_util.h"

namespace fs = std::filesystem;

namespace {

using specula::test::RunResult;
using specula::test::run_cli;
using specula::test::slurp;

class Cli : public ::testing::Test {
 protected:
  void SetUp() override {
    if (std::string(SPECULA_CLI_PATH).empty()) GTEST_SKIP() << "specula CLI not built";
    dir_ = specula::test::temp_dir(::testing::UnitTest::GetInstance()->current_test_info()->name());
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }
  fs::path write(const std::string& name, const std::string& text) {
    const fs::path p = dir_ / name;
    std::ofstream(p, std::ios::binary) << text;
    return p;
  }
  fs::path dir_;
};

// Two triangles in file order: a quad in the z = 0 plane (fan-triangulated: (0,1,2), (0,2,3)).
constexpr const char* kQuadObj =
    "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
    "f 1 2 3 4\n";

}  // namespace

TEST_F(Cli, HelpOnEverySubcommand) {
  for (const char* sub : {"", "render ", "trace ", "info ", "bench ", "bench trace ", "bench render ", "bench svo ", "voxelize "}) {
    const RunResult r = run_cli(std::string(sub) + "--help", dir_);
    EXPECT_EQ(r.exit_code, 0) << sub;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << sub << r.out;
  }
  // No command at all: the list of commands (a usage error all the same), not just "a
  // subcommand is required".
  const RunResult bare = run_cli("", dir_);
  EXPECT_EQ(bare.exit_code, 2);
  for (const char* sub : {"render", "trace", "info", "bench", "voxelize"})
    EXPECT_NE(bare.err.find(std::string("\n  ") + sub + " "), std::string::npos) << sub << "\n" << bare.err;
  const RunResult bench = run_cli("bench", dir_);
  EXPECT_EQ(bench.exit_code, 2);
  for (const char* sub : {"trace", "render", "svo"})
    EXPECT_NE(bench.err.find(std::string("\n  ") + sub + " "), std::string::npos) << sub << "\n" << bench.err;
  // A mistyped command is named, with the commands there are.
  const RunResult frob = run_cli("frob", dir_);
  EXPECT_EQ(frob.exit_code, 2);
  EXPECT_NE(frob.err.find("specula: error: 'frob' is not a command (render, trace, info, bench, voxelize)"),
            std::string::npos)
      << frob.err;
  const RunResult tarce = run_cli("bench tarce", dir_);
  EXPECT_EQ(tarce.exit_code, 2);
  EXPECT_NE(tarce.err.find("specula: error: 'tarce' is not a bench command (trace, render, svo)"), std::string::npos)
      << tarce.err;
  EXPECT_NE(tarce.err.find("Run 'specula bench --help'"), std::string::npos) << tarce.err;
}

// A camera inside an occupied voxel sees little but that voxel (every primary ray hits it at
// t = 0, as at coarse depths): render says so; a camera outside it, or a triangle render, not.
TEST_F(Cli, CameraInsideAnOccupiedVoxelIsAWarning) {
  write("quad.obj", kQuadObj);  // z = 0: the root cube is [-1, 1] x [-1, 1] x [0, 2]
  const fs::path json = write("scene.json", R"({"meshes": [{"file": "quad.obj"}], "cameras": [
      {"name": "in", "position": [0.5, 0.5, 0.5], "target": [0, 0, 0]},
      {"name": "out", "position": [0, 0, 5], "target": [0, 0, 0]}]})");
  const std::string args = " --width 8 --height 8 -o '" + (dir_ / "x.png").string() + "'";
  const std::string warning = "warning: camera 'in' is inside an occupied voxel (depth 1)";
  for (const char* accel : {"svo", "grid"}) {
    RunResult r = run_cli("render '" + json.string() + "' --camera in --accel " + accel + " --depth 1" + args, dir_);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.err.find(warning), std::string::npos) << accel << "\n" << r.err;
    r = run_cli("render '" + json.string() + "' --camera out --accel " + accel + " --depth 1" + args, dir_);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_EQ(r.err.find("inside an occupied voxel"), std::string::npos) << accel << "\n" << r.err;
  }
  // Depth 3: the camera's voxel, [0.5, 0.75) on every axis, holds no part of the quad.
  RunResult r = run_cli("render '" + json.string() + "' --camera in --accel svo --depth 3" + args, dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err.find("inside an occupied voxel"), std::string::npos) << r.err;
  r = run_cli("render '" + json.string() + "' --camera in" + args, dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err.find("inside an occupied voxel"), std::string::npos) << r.err;
  // bench render names such cameras after its table, and in its JSON.
  r = run_cli("bench render --scene '" + json.string() + "' --accel svo --depth 1 --sizes 8x8 --frames 1", dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("not the view): in\n"), std::string::npos) << r.out;
  r = run_cli("bench render --scene '" + json.string() + "' --accel svo --depth 1 --sizes 8x8 --frames 1 --json", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  nlohmann::json j;
  ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
  ASSERT_EQ(j["results"].size(), 2u) << r.out;
  EXPECT_TRUE(j["results"][0]["camera_in_voxel"].get<bool>()) << r.out;
  EXPECT_FALSE(j["results"][1]["camera_in_voxel"].get<bool>()) << r.out;
}

TEST_F(Cli, TracePrintsDistanceAndFileOrderPrimitive) {
  const fs::path obj = write("quad.obj", kQuadObj);
  // Ray 1 hits the lower-right triangle (prim 0), ray 2 the upper-left (prim 1), ray 3 misses.
  const fs::path rays = write("rays.txt", "0.5 -0.5 2 0 0 -1\n-0.5 0.5 -3 0 0 1\n\n5 5 5 0 0 -1\n");
  const RunResult r = run_cli("trace '" + obj.string() + "' --rays '" + rays.string() + "'", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "2 0\n3 1\nmiss\n");
}

TEST_F(Cli, TraceStatsGoToStderr) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const fs::path rays = write("rays.txt", "0.5 -0.5 2 0 0 -1\n");
  const RunResult r = run_cli("trace '" + obj.string() + "' --rays '" + rays.string() + "' --stats --repeat 3", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "2 0\n");
  for (const char* key : {"load", "build", "trace", "Mrays/s"}) EXPECT_NE(r.err.find(key), std::string::npos) << r.err;
  // The build line is render's (nodes, leaves, depth, SAH cost, MiB); one ray is "1 ray".
  for (const char* key : {"(bvh: ", " leaves, depth ", " MiB)", "(1 ray, 1 thread, median of 3 passes)"})
    EXPECT_NE(r.err.find(key), std::string::npos) << key << "\n" << r.err;
}

TEST_F(Cli, MalformedRayFileNamesTheLine) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const fs::path rays = write("rays.txt", "0 0 1 0 0 -1\n0 0 1 0 zero -1\n");
  const RunResult r = run_cli("trace '" + obj.string() + "' --rays '" + rays.string() + "'", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_FALSE(r.signaled);
  EXPECT_NE(r.err.find("rays.txt: line 2"), std::string::npos) << r.err;
}

TEST_F(Cli, MissingSceneIsAClearError) {
  const RunResult r = run_cli("render '" + (dir_ / "nope.obj").string() + "' -o '" + (dir_ / "x.png").string() + "'", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("nope.obj"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
}

// An image whose film could not be allocated is refused before the scene is read: the error
// is about the size although the scene does not even exist (it would otherwise come after the
// load and the build, seconds into a big scene).
TEST_F(Cli, AbsurdImageSizeFailsBeforeTheSceneIsLoaded) {
  const std::string missing = "'" + (dir_ / "nope.obj").string() + "'";
  RunResult r = run_cli("render " + missing + " --width 32768 --height 32768 -o '" + (dir_ / "x.png").string() + "'", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("image size 32768x32768 needs 12288 MiB of film (limit 2048 MiB)"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("nope.obj"), std::string::npos) << r.err;
  EXPECT_EQ(r.out.find("load"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
  // The AOV planes count: 16384x8192 is 1.5 GiB of colour alone, 2.5 GiB with a normal AOV.
  r = run_cli("render " + missing + " --width 16384 --height 8192 --aov normal -o '" + (dir_ / "x.png").string() + "'", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("needs 3072 MiB of film"), std::string::npos) << r.err;
  r = run_cli("bench render --scene " + missing + " --sizes 640x480,16384x16384", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--sizes: image size 16384x16384 needs 3072 MiB of film"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("nope.obj"), std::string::npos) << r.err;
}

// The voxelizer's refusal names --memory-limit: every command that voxelizes a scene takes it.
TEST_F(Cli, VoxelizingCommandsTakeTheMemoryLimit) {
  const std::string out = " -o '" + (dir_ / "x.png").string() + "'";
  RunResult r = run_cli("render cornell --accel svo --depth 5 --width 8 --height 8 --memory-limit 1K" + out, dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("exceeds the memory limit of 1024 bytes"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("lattice copy of the"), std::string::npos) << r.err;  // not "0 voxel-triangle pairs"
  EXPECT_NE(r.err.find("--memory-limit"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
  r = run_cli("render cornell --accel grid --depth 5 --width 8 --height 8 --memory-limit 100K" + out, dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("upper bound for"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("limit of 102400 bytes"), std::string::npos) << r.err;
  r = run_cli("render cornell --accel svo --depth 5 --width 8 --height 8 --memory-limit 1G" + out, dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "x.png"));
  r = run_cli("bench render --scene cornell --accel svo --depth 5 --sizes 8x8 --frames 1 --memory-limit 1K", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("exceeds the memory limit of 1024 bytes"), std::string::npos) << r.err;
  r = run_cli("bench svo --scene cornell --depths 5 --sizes 8x8 --memory-limit 1K", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("exceeds the memory limit of 1024 bytes"), std::string::npos) << r.err;
  EXPECT_EQ(run_cli("render cornell --memory-limit lots" + out, dir_).exit_code, 2);
}

// Mistakes that only the options show fail before any work: an output that cannot be written,
// contradicting options. Each run names a scene that does not exist, so an error about the
// scene would show that the load came first.
TEST_F(Cli, OutputAndOptionMistakesFailBeforeTheLoad) {
  const std::string missing = "'" + (dir_ / "nope.obj").string() + "'";
  const auto expect_early = [&](const std::string& args, const std::string& message) {
    const RunResult r = run_cli(args, dir_);
    EXPECT_EQ(r.exit_code, 1) << args;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << "\n" << r.err;
    EXPECT_EQ(r.err.find("nope.obj"), std::string::npos) << args << "\n" << r.err;
    EXPECT_EQ(r.out.find("load"), std::string::npos) << args << "\n" << r.out;
  };
  const std::string no_dir = (dir_ / "no-such-folder" / "x.png").string();
  expect_early("render " + missing + " -o '" + no_dir + "'", "no-such-folder does not exist");
  fs::create_directory(dir_ / "folder.png");
  expect_early("render " + missing + " -o '" + (dir_ / "folder.png").string() + "'", "is a directory");
  expect_early("voxelize " + missing + " --depth 4 -o '" + (dir_ / "no-such-folder" / "v.svo").string() + "'",
               "does not exist");
  expect_early("voxelize " + missing + " --depth 4 --format xyz -o '" + (dir_ / "v.svo").string() + "'",
               "--format xyz with -o");
  expect_early("voxelize " + missing + " --depth 4 --no-attributes -o '" + (dir_ / "v.svo").string() + "'",
               "--no-attributes with -o");
  expect_early("voxelize " + missing + " --depth 4 -o '" + (dir_ / "v.txt").string() + "'",
               "v.txt: unsupported voxel output '.txt' (supported: .xyz, .svo)");
  expect_early("voxelize " + missing + " --depth 4 --format xyz -o '" + (dir_ / "voxels").string() + "'",
               "voxels: the output's extension chooses its format, and it has none: name it FILE.xyz");
  expect_early("render " + missing + " --accel svo --depth 6 --lod 9", "--lod 9 is deeper than the octree (--depth 6)");
  expect_early("render " + missing + " --accel grid --lod 2", "--lod needs --accel svo");
}

// An error comes after the lines the command printed before it, also in a log of both streams
// (the standard output is buffered when it is not a terminal).
TEST_F(Cli, ErrorsFollowTheOutputThatPrecededThem) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const fs::path log = dir_ / "both.txt";
  const std::string cmd = std::string("'") + SPECULA_CLI_PATH + "' render '" + obj.string() +
                          "' --camera nope -o '" + (dir_ / "x.png").string() + "' >'" + log.string() +
                          "' 2>&1 </dev/null";
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 1);
  const std::string text = slurp(log);
  const size_t load = text.find("load "), error = text.find("specula: error: unknown camera 'nope'");
  ASSERT_NE(load, std::string::npos) << text;
  ASSERT_NE(error, std::string::npos) << text;
  EXPECT_LT(load, error) << text;
}

// A mesh folder that does not exist is said so, not skipped in favour of the next one.
TEST_F(Cli, DataFolderThatDoesNotExistIsReported) {
  const fs::path mesh = write("quad.obj", kQuadObj);
  const std::string missing = (dir_ / "no-such-meshes").string();
  const RunResult r = run_cli("info '" + mesh.string() + "' --data '" + missing + "'", dir_);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--data"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("no-such-meshes"), std::string::npos) << r.err;
  const char* old = std::getenv("SPECULA_DATA");
  const std::string saved = old ? old : "";
  ::setenv("SPECULA_DATA", missing.c_str(), 1);
  const RunResult env = run_cli("info '" + mesh.string() + "'", dir_);
  if (old) ::setenv("SPECULA_DATA", saved.c_str(), 1);
  else ::unsetenv("SPECULA_DATA");
  EXPECT_EQ(env.exit_code, 0) << env.err;  // a warning: the file given needs no mesh folder
  EXPECT_NE(env.err.find("warning: SPECULA_DATA=" + missing + " is not a folder"), std::string::npos) << env.err;
}

// voxelize --table runs every strategy and writes nothing: a strategy or an output with it is a
// usage error, as are a memory limit and --no-memory-limit together.
TEST_F(Cli, VoxelizeOptionsThatContradictAreUsageErrors) {
  const fs::path mesh = write("quad.obj", kQuadObj);
  const std::string m = "voxelize '" + mesh.string() + "' --depth 3";
  for (const std::string& extra : {std::string(" --table --tests aabb"), std::string(" --table --sat-at all"),
                                   std::string(" --table --traversal octree"), std::string(" --table --no-clip-shortcut"),
                                   std::string(" --table --format xyz"),
                                   " --table -o '" + (dir_ / "t.svo").string() + "'",
                                   std::string(" --memory-limit 1G --no-memory-limit")}) {
    const RunResult r = run_cli(m + extra, dir_);
    EXPECT_EQ(r.exit_code, 2) << extra << "\n" << r.out;
    EXPECT_NE(r.err.find("excludes"), std::string::npos) << extra << "\n" << r.err;
  }
  EXPECT_FALSE(fs::exists(dir_ / "t.svo"));
  EXPECT_EQ(run_cli(m + " --table", dir_).exit_code, 0);
  EXPECT_EQ(run_cli(m + " --no-attributes -o '" + (dir_ / "t.xyz").string() + "'", dir_).exit_code, 0);
}

// The same check for a .svo file, whose depth is only known once it is read.
TEST_F(Cli, LodDeeperThanAnSvoFileIsAnError) {
  const fs::path mesh = write("quad.obj", kQuadObj);
  const fs::path svo = dir_ / "quad.svo";
  ASSERT_EQ(run_cli("voxelize '" + mesh.string() + "' --depth 3 -o '" + svo.string() + "'", dir_).exit_code, 0);
  const std::string out = " -o '" + (dir_ / "x.png").string() + "' --width 8 --height 8";
  RunResult r = run_cli("render '" + svo.string() + "' --lod 4" + out, dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("has depth 3 (use 1..3, or 0 for full depth)"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
  r = run_cli("render '" + svo.string() + "' --lod 3" + out, dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
}

// A camera name the scene does not have fails once the scene is loaded, before its tracer is
// built (a depth-10 octree or a large BVH) and before any other view is rendered.
TEST_F(Cli, UnknownCameraFailsBeforeTheBuild) {
  const fs::path mesh = write("quad.obj", kQuadObj);
  const fs::path svo = dir_ / "quad.svo";
  ASSERT_EQ(run_cli("voxelize '" + mesh.string() + "' --depth 3 -o '" + svo.string() + "'", dir_).exit_code, 0);
  const std::string m = "'" + mesh.string() + "'";
  const std::string img = " -o '" + (dir_ / "x.png").string() + "' --width 8 --height 8";
  for (const std::string& args :
       {"render " + m + " --camera nosuch" + img, "render " + m + " --camera nosuch --accel svo --depth 5" + img,
        "render '" + svo.string() + "' --camera nosuch" + img, "bench render --scene " + m + " --cameras default,nosuch --sizes 8x8",
        "bench svo --scene " + m + " --cameras nosuch --sizes 8x8 --depths 2"}) {
    const RunResult r = run_cli(args, dir_);
    EXPECT_EQ(r.exit_code, 1) << args;
    EXPECT_NE(r.err.find("unknown camera 'nosuch' (available: "), std::string::npos) << args << "\n" << r.err;
    EXPECT_EQ(r.out.find("build"), std::string::npos) << args << "\n" << r.out;
    EXPECT_EQ(r.out.find("voxelize"), std::string::npos) << args << "\n" << r.out;
    EXPECT_EQ(r.out.find("default "), std::string::npos) << args << " rendered a view first\n" << r.out;
  }
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
}

// Results printed to a standard output that cannot take them (a full disk: /dev/full) end in an
// error, not in success with a truncated result.
TEST_F(Cli, FailedWritesToStandardOutputAreErrors) {
  if (!fs::exists("/dev/full")) GTEST_SKIP() << "no /dev/full on this system";
  const fs::path mesh = write("quad.obj", kQuadObj);
  const fs::path rays = write("rays.txt", "0 0 1 0 0 -1\n0.5 0.5 1 0 0 -1\n");
  const fs::path err = dir_ / "stderr.txt";
  const auto run_full = [&](const std::string& args) {
    const std::string cmd = std::string("'") + SPECULA_CLI_PATH + "' " + args + " >/dev/full 2>'" + err.string() + "' </dev/null";
    const int status = std::system(cmd.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  };
  EXPECT_EQ(run_full("trace '" + mesh.string() + "' --rays '" + rays.string() + "'"), 1);
  EXPECT_NE(slurp(err).find("writing the standard output failed"), std::string::npos) << slurp(err);
  EXPECT_EQ(run_full("voxelize '" + mesh.string() + "' --depth 8 --format xyz"), 1);
  EXPECT_NE(slurp(err).find("writing the standard output failed"), std::string::npos) << slurp(err);
  // The same commands succeed when the output can be written.
  EXPECT_EQ(run_cli("trace '" + mesh.string() + "' --rays '" + rays.string() + "'", dir_).exit_code, 0);
}

// EXR images are linear: a tone mapping asked for with one is reported as not applied.
TEST_F(Cli, TonemapWithAnExrImageIsAWarning) {
  const std::string args = " --width 8 --height 8 -o '" + (dir_ / "x.exr").string() + "'";
  RunResult r = run_cli("render cornell --tonemap reinhard" + args, dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: --tonemap reinhard applies to PNG images"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "x.exr"));
  r = run_cli("render cornell" + args, dir_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err.find("--tonemap"), std::string::npos) << r.err;
}

TEST_F(Cli, BadOptionsAreUsageErrors) {
  EXPECT_EQ(run_cli("render cornell --accel octree", dir_).exit_code, 2);
  EXPECT_EQ(run_cli("render cornell --width 100000", dir_).exit_code, 2);
  {  // CLI11's usage errors read like every other error and name the command's help
    const RunResult u = run_cli("render cornell --width 0", dir_);
    EXPECT_EQ(u.exit_code, 2);
    EXPECT_NE(u.err.find("specula: error: --width: Value 0 not in range"), std::string::npos) << u.err;
    EXPECT_NE(u.err.find("Run 'specula render --help' for the options."), std::string::npos) << u.err;
    const RunResult b = run_cli("bench trace --no-such-flag", dir_);
    EXPECT_EQ(b.exit_code, 2);
    EXPECT_NE(b.err.find("specula: error: The following argument was not expected: --no-such-flag"), std::string::npos)
        << b.err;
    EXPECT_NE(b.err.find("Run 'specula bench trace --help'"), std::string::npos) << b.err;
  }
  EXPECT_EQ(run_cli("render", dir_).exit_code, 2);
  EXPECT_EQ(run_cli("render cornell --no-such-flag", dir_).exit_code, 2);
  const RunResult r = run_cli("render cornell -o '" + (dir_ / "x.bmp").string() + "'", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find(".png or .exr"), std::string::npos) << r.err;
}

TEST_F(Cli, RenderWritesImageAndPrintsTimings) {
  const fs::path png = dir_ / "cornell.png";
  const RunResult r = run_cli("render cornell --width 64 --height 48 --aov depth,cost -o '" + png.string() + "'", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* key : {"load", "build", "render", "Mrays/s", " ms"}) EXPECT_NE(r.out.find(key), std::string::npos) << r.out;
  // The build line names the traversal kernel auto chose; --bvh-kernel sse4 is honoured.
  EXPECT_TRUE(r.out.find("(bvh sse4: ") != std::string::npos || r.out.find("(bvh avx") != std::string::npos) << r.out;
  const RunResult k = run_cli("render cornell --width 8 --height 6 --bvh-kernel sse4 -o '" + (dir_ / "k.png").string() + "'", dir_);
  ASSERT_EQ(k.exit_code, 0) << k.err;
  EXPECT_NE(k.out.find("(bvh sse4: "), std::string::npos) << k.out;
  // --bvh-quality high builds the optimised tree and says what the optimisation did; the image
  // is the same bytes as the fast tree's (the same hits).
  const RunResult h = run_cli("render cornell --width 8 --height 6 --bvh-kernel sse4 --bvh-quality high -o '" +
                                  (dir_ / "h.png").string() + "'",
                              dir_);
  ASSERT_EQ(h.exit_code, 0) << h.err;
  EXPECT_NE(h.out.find("--bvh-quality high: SAH cost "), std::string::npos) << h.out;
  EXPECT_EQ(k.out.find("--bvh-quality high"), std::string::npos) << k.out;
  {
    std::ifstream a(dir_ / "k.png", std::ios::binary), b(dir_ / "h.png", std::ios::binary);
    const std::string ka((std::istreambuf_iterator<char>(a)), {}), hb((std::istreambuf_iterator<char>(b)), {});
    EXPECT_FALSE(ka.empty());
    EXPECT_EQ(ka, hb) << "--bvh-quality high changed the image";
  }
  const RunResult bad = run_cli("render cornell --bvh-quality best", dir_);
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.err.find("--bvh-quality"), std::string::npos) << bad.err;
  EXPECT_TRUE(fs::exists(png));
  EXPECT_TRUE(fs::exists(dir_ / "cornell.depth.png"));
  EXPECT_TRUE(fs::exists(dir_ / "cornell.cost.png"));
  // No temporary files left behind.
  for (const auto& e : fs::directory_iterator(dir_))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
}

TEST_F(Cli, RenderRefusesToOverwriteItsInput) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const fs::path png = dir_ / "quad.png";
  fs::copy_file(obj, png);  // a "scene" that happens to have the output's name
  const RunResult r = run_cli("render '" + png.string() + "' -o '" + png.string() + "'", dir_);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(slurp(png), kQuadObj);
}

TEST_F(Cli, OutputNeverOverwritesAnInputHoweverSpelled) {
  const fs::path obj = write("quad.obj", kQuadObj);
  fs::create_directory(dir_ / "sub");
  fs::create_symlink(obj, dir_ / "link.png");
  fs::create_hard_link(obj, dir_ / "hard.png");
  fs::create_symlink(obj, dir_ / "aov.depth.png");
  fs::create_symlink(obj, dir_ / "link.svo");
  fs::create_hard_link(obj, dir_ / "hard.xyz");
  const std::string d = dir_.string();
  struct Case {
    std::string args, refused;
  };
  const std::vector<Case> cases{
      {"render '" + d + "/./quad.obj' -o '" + d + "/link.png'", d + "/link.png"},
      {"render '" + d + "/sub/../quad.obj' -o '" + d + "/sub/../hard.png'", d + "/sub/../hard.png"},
      {"render '" + d + "/quad.obj' --aov depth -o '" + d + "/aov.png'", d + "/aov.depth.png"},
      {"voxelize '" + d + "/./quad.obj' --depth 3 -o '" + d + "/link.svo'", d + "/link.svo"},
      {"voxelize '" + d + "/quad.obj' --depth 3 -o '" + d + "/sub/../hard.xyz'", d + "/sub/../hard.xyz"},
  };
  for (const Case& c : cases) {
    const RunResult r = run_cli(c.args, dir_);
    EXPECT_EQ(r.exit_code, 1) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.refused + ": refusing to overwrite the input"), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(slurp(obj), kQuadObj) << c.args;
    EXPECT_TRUE(fs::is_symlink(dir_ / "link.png"));
    EXPECT_TRUE(fs::is_symlink(dir_ / "link.svo"));
  }
  for (const auto& e : fs::directory_iterator(dir_))
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos) << e.path();
}

TEST_F(Cli, RenderNeverOverwritesTheSkyImage) {
  specula::write_png((dir_ / "sky.png").string(), 4, 2, std::vector<specula::Vec3>(8, specula::Vec3{0.2f, 0.4f, 0.8f}));
  const std::string sky = slurp(dir_ / "sky.png");
  write("quad.obj", kQuadObj);
  const fs::path json = write("scene.json", R"({"meshes": [{"file": "quad.obj"}], "sky": {"type": "image", "image": "sky.png"}})");
  const std::string d = dir_.string();
  for (const std::string& out : {d + "/sky.png", d + "/./sky.png", d + "/sub/../sky.png"}) {
    fs::create_directories(dir_ / "sub");
    const RunResult r = run_cli("render '" + json.string() + "' --width 8 --height 6 -o '" + out + "'", dir_);
    EXPECT_EQ(r.exit_code, 1) << out << "\n" << r.err;
    EXPECT_NE(r.err.find("refusing to overwrite the input file"), std::string::npos) << r.err;
    EXPECT_EQ(slurp(dir_ / "sky.png"), sky) << out;
  }
  fs::rename(dir_ / "sky.png", dir_ / "x.depth.png");
  write("scene.json", R"({"meshes": [{"file": "quad.obj"}], "sky": {"type": "image", "image": "x.depth.png"}})");
  const RunResult aov = run_cli("render '" + json.string() + "' --width 8 --height 6 --aov depth -o '" + d + "/x.png'", dir_);
  EXPECT_EQ(aov.exit_code, 1) << aov.err;
  EXPECT_NE(aov.err.find("x.depth.png: refusing to overwrite the input file"), std::string::npos) << aov.err;
  EXPECT_EQ(slurp(dir_ / "x.depth.png"), sky);
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
  // A different output is fine.
  EXPECT_EQ(run_cli("render '" + json.string() + "' --width 8 --height 6 -o '" + d + "/y.png'", dir_).exit_code, 0);
}

TEST_F(Cli, InfoDescribesAMesh) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const RunResult r = run_cli("info '" + obj.string() + "'", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("triangles  2"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("bounds     [-1 -1 0] - [1 1 0]"), std::string::npos) << r.out;
}

namespace {
/// A bench command's JSON names the processor it ran on (cli::cpu_info).
void expect_cpu(const nlohmann::json& j) {
  ASSERT_TRUE(j.contains("cpu")) << j.dump();
  EXPECT_FALSE(j["cpu"]["name"].get<std::string>().empty()) << j["cpu"].dump();
  EXPECT_GE(j["cpu"]["logical_cpus"].get<int>(), 1) << j["cpu"].dump();
  const std::string isa = j["cpu"]["isa"].get<std::string>();
  EXPECT_TRUE(isa == "avx512" || isa == "avx2" || isa == "sse" || isa == "scalar") << isa;
}
}  // namespace

TEST_F(Cli, BenchTraceJsonHasEveryRayKindAndTheKernel) {
  const RunResult r = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --bvh-kernel sse4 --json", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  nlohmann::json j;
  ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
  EXPECT_EQ(j["triangles"].get<int>() > 0, true);
  EXPECT_EQ(j["bvh"]["kernel"], "sse4");
  EXPECT_GT(j["bvh"]["sah_cost"].get<double>(), 0.0);
  expect_cpu(j);
  std::vector<std::string> kinds;
  for (const auto& k : j["results"]) {
    kinds.push_back(k["kind"].get<std::string>());
    EXPECT_GT(k["count"].get<int>(), 0) << k.dump();
    EXPECT_GT(k["specula_1t"].get<double>(), 0.0) << k.dump();
    EXPECT_GT(k["specula_nt"].get<double>(), 0.0) << k.dump();
    if (j["embree"].get<bool>()) {
      EXPECT_GT(k["ratio_1t"].get<double>(), 0.0) << k.dump();
    }
    // Every ray visits the root at least; a triangle count per ray is reported too.
    if (k["kind"] != "build") {
      EXPECT_GE(k["nodes_per_ray"].get<double>(), 1.0) << k.dump();
      EXPECT_GE(k["triangles_per_ray"].get<double>(), 0.0) << k.dump();
    } else {
      EXPECT_FALSE(k.contains("nodes_per_ray")) << k.dump();
    }
  }
  EXPECT_EQ(kinds, (std::vector<std::string>{"build", "primary", "shadow", "reflection", "refraction", "diffuse", "random"}));
  // --embree-robust: Embree's watertight test (RTC_SCENE_FLAG_ROBUST), named in the JSON.
  if (j["embree"].get<bool>()) {
    EXPECT_EQ(j["embree_scene_flags"], "none");
    // Embree's binned SAH builder given our objective, its binary tree scored by our formula:
    // ours is no worse on this scene (22.82 against 23.13 when recorded).
    const nlohmann::json& es = j["embree_sah"];
    EXPECT_EQ(es["nodes"].get<int>(), 2 * es["leaves"].get<int>() - 1) << es.dump();
    EXPECT_GE(es["sah_cost"].get<double>(), 1.0) << es.dump();
    EXPECT_LE(j["bvh"]["sah_cost"].get<double>(), 1.02 * es["sah_cost"].get<double>()) << es.dump();
    const RunResult rb = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --embree-robust --json", dir_);
    ASSERT_EQ(rb.exit_code, 0) << rb.err;
    const nlohmann::json rj = nlohmann::json::parse(rb.out);
    EXPECT_EQ(rj["embree_scene_flags"], "robust");
    for (const auto& k : rj["results"]) EXPECT_GT(k["embree_1t"].get<double>(), 0.0) << k.dump();
  }
  // The table names the same kinds.
  const RunResult t = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree", dir_);
  ASSERT_EQ(t.exit_code, 0) << t.err;
  for (const char* k : {"primary", "shadow", "reflection", "refraction", "diffuse", "random"})
    EXPECT_NE(t.out.find(std::string("\n") + k + " "), std::string::npos) << k << "\n" << t.out;
  EXPECT_NE(t.out.find("nodes/ray"), std::string::npos) << t.out;
  EXPECT_NE(t.out.find("\ncpu: "), std::string::npos) << t.out;  // which processor the figures are from
  // One column per thread count: "2T" beside "1T" with two threads; with one thread a single
  // column (not the one-thread figures twice), and the JSON's all-threads figures are those.
  const RunResult t2 = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree --threads 2", dir_);
  ASSERT_EQ(t2.exit_code, 0) << t2.err;
  EXPECT_NE(t2.out.find("specula 1T   specula 2T"), std::string::npos) << t2.out;
  EXPECT_NE(t2.out.find(", 2 threads,"), std::string::npos) << t2.out;
  const RunResult t1 = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree --threads 1", dir_);
  ASSERT_EQ(t1.exit_code, 0) << t1.err;
  EXPECT_NE(t1.out.find("|   specula 1T | nodes/ray"), std::string::npos) << t1.out;
  EXPECT_EQ(t1.out.find("specula 1T   specula 1T"), std::string::npos) << t1.out;
  EXPECT_NE(t1.out.find(", 1 thread,"), std::string::npos) << t1.out;
  const RunResult j1 = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree --threads 1 --json", dir_);
  ASSERT_EQ(j1.exit_code, 0) << j1.err;
  // Parsed into a local: a temporary's member in the range would not outlive the loop's start.
  const nlohmann::json j1_json = nlohmann::json::parse(j1.out);
  for (const auto& k : j1_json["results"])
    EXPECT_EQ(k["specula_nt"].get<double>(), k["specula_1t"].get<double>()) << k.dump();
  EXPECT_NE(run_cli("bench trace --scene cornell --bvh-kernel avx9", dir_).exit_code, 0);
  // --embree-robust asks for an Embree comparison: with --no-embree it is a usage error.
  const RunResult robust_none = run_cli("bench trace --scene cornell --no-embree --embree-robust", dir_);
  EXPECT_EQ(robust_none.exit_code, 2);
  EXPECT_NE(robust_none.err.find("excludes"), std::string::npos) << robust_none.err;
  // --mesh replaces --scene: both at once is a usage error, not one of them silently dropped.
  const RunResult both = run_cli("bench trace --scene cornell --mesh x.obj", dir_);
  EXPECT_EQ(both.exit_code, 2);
  EXPECT_NE(both.err.find("excludes"), std::string::npos) << both.err;
  // --bvh-quality high: the JSON names the quality and the optimisation's figures.
  const RunResult hq = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree --bvh-quality high --json", dir_);
  ASSERT_EQ(hq.exit_code, 0) << hq.err;
  const nlohmann::json hj = nlohmann::json::parse(hq.out);
  EXPECT_EQ(hj["bvh"]["quality"], "high");
  EXPECT_GE(hj["bvh"]["sah_cost_binned"].get<double>(), hj["bvh"]["sah_cost"].get<double>());
  EXPECT_GT(hj["bvh"]["optimize_ms"].get<double>(), 0.0);
  EXPECT_EQ(j["bvh"]["quality"], "fast");
  // A scene in zones also times one BVH per zone (seed 002's build), in JSON and in the table.
  const RunResult z = run_cli("bench trace --scene city:10000 --width 8 --height 6 --repeat 1 --no-embree --json", dir_);
  ASSERT_EQ(z.exit_code, 0) << z.err;
  const nlohmann::json zj = nlohmann::json::parse(z.out);
  ASSERT_TRUE(zj.contains("zones")) << z.out;
  EXPECT_GT(zj["zones"]["count"].get<int>(), 10);
  EXPECT_EQ(zj["zones"]["triangles"].get<int>(), zj["triangles"].get<int>());
  EXPECT_GT(zj["zones"]["build_ms_1t"].get<double>(), 0.0);
  const fs::path quad = write("quad.obj", kQuadObj);
  const RunResult one = run_cli("bench trace --mesh " + quad.string() + " --width 8 --height 6 --repeat 1 --no-embree --json", dir_);
  ASSERT_EQ(one.exit_code, 0) << one.err;
  EXPECT_FALSE(nlohmann::json::parse(one.out).contains("zones")) << "a bare mesh is one zone: " << one.out;
  if (j["embree"].get<bool>()) {
    // Two triangles are one leaf for both builders (one block of four): cost 2, one node.
    const RunResult eq = run_cli("bench trace --mesh " + quad.string() + " --width 8 --height 6 --repeat 1 --json", dir_);
    ASSERT_EQ(eq.exit_code, 0) << eq.err;
    const nlohmann::json qj = nlohmann::json::parse(eq.out);
    EXPECT_EQ(qj["embree_sah"]["sah_cost"].get<double>(), 2.0) << eq.out;
    EXPECT_EQ(qj["embree_sah"]["nodes"].get<int>(), 1) << eq.out;
    EXPECT_EQ(qj["bvh"]["sah_cost"].get<double>(), 2.0) << eq.out;
  }
}

TEST_F(Cli, BenchRenderPrintsFrameRatesAndSeedFigures) {
  // A tiny size, so no seed row: the pool's own cameras are timed and the table is printed.
  const RunResult r = run_cli("bench render --cameras water,bunny --sizes 32x24,16x12 --frames 1", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("seed 000 GPU fps"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("water      32x24"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("bunny      16x12"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("parallel"), std::string::npos) << r.out;
  const RunResult bad = run_cli("bench render --sizes 640by480", dir_);
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.err.find("--sizes: '640by480' is not WxH"), std::string::npos) << bad.err;
  const RunResult cam = run_cli("bench render --cameras nope --sizes 8x8 --frames 1", dir_);
  EXPECT_NE(cam.exit_code, 0);
  EXPECT_NE(cam.err.find("nope"), std::string::npos) << cam.err;
}

// --json: stdout carries one JSON object and nothing else (the load lines go to stderr).
TEST_F(Cli, BenchRenderAndBenchSvoPrintJson) {
  const RunResult r = run_cli("bench render --cameras water --sizes 640x480,16x12 --frames 1 --no-shadows --json", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  nlohmann::json j;
  ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
  EXPECT_NE(r.err.find("load"), std::string::npos) << r.err;
  EXPECT_EQ(j["scene"], "pool");
  EXPECT_EQ(j["accel"], "bvh");
  EXPECT_FALSE(j["shadows"].get<bool>());
  expect_cpu(j);
  EXPECT_GT(j["build_ms"].get<double>(), 0.0);
  ASSERT_EQ(j["results"].size(), 2u) << r.out;
  const nlohmann::json& big = j["results"][0];
  EXPECT_EQ(big["camera"], "water");
  EXPECT_EQ(big["width"], 640);
  EXPECT_GT(big["fps"].get<double>(), 0.0);
  EXPECT_EQ(big["primary_rays"], 640 * 480);
  EXPECT_EQ(big["shadow_rays"], 0);
  ASSERT_EQ(big["seed000_gpu_fps"].size(), 8u) << big.dump();
  EXPECT_TRUE(big["seed000_gpu_fps"][0].is_null());      // no water figure at depth 1
  EXPECT_EQ(big["seed000_gpu_fps"][2].get<double>(), 25.0);  // depth 3
  EXPECT_EQ(big["seed000_gpu_fps"][6].get<double>(), 7.4);   // the seed's 7.4, not a float's 7.400000095
  EXPECT_NEAR(big["ratio_seed000_d3"].get<double>(), big["fps"].get<double>() / 25.0, 1e-9);
  EXPECT_FALSE(j["results"][1].contains("seed000_gpu_fps"));  // no seed figure at 16x12

  const RunResult s = run_cli("bench svo --cameras water --sizes 640x480 --depths 3,4 --frames 1 --json", dir_);
  ASSERT_EQ(s.exit_code, 0) << s.err;
  ASSERT_NO_THROW(j = nlohmann::json::parse(s.out)) << s.out;
  ASSERT_EQ(j["depths"].size(), 2u);
  EXPECT_EQ(j["depths"][1]["depth"], 4);
  expect_cpu(j);
  EXPECT_NE(s.err.find("\ncpu: "), std::string::npos) << s.err;  // the header, on stderr with --json
  EXPECT_GT(j["depths"][1]["voxels"].get<int>(), j["depths"][0]["voxels"].get<int>());
  ASSERT_EQ(j["cells"].size(), 8u);  // 2 depths x 2 setups x 2 hit modes
  int with_seed = 0;
  for (const auto& c : j["cells"]) {
    EXPECT_GT(c["fps"].get<double>(), 0.0) << c.dump();
    EXPECT_GE(c["rays_per_pixel"].get<double>(), 1.0) << c.dump();
    if (c.contains("seed000_gpu_fps")) {
      ++with_seed;
      EXPECT_EQ(c["setup"], "seed000") << c.dump();
      EXPECT_EQ(c["seed000_gpu_fps"].get<double>(), c["depth"] == 3 ? 25.0 : 17.0) << c.dump();
    }
    EXPECT_FALSE(c["camera_in_voxel"].get<bool>()) << c.dump();  // the water camera is above the pool
  }
  EXPECT_EQ(with_seed, 4);  // the seed's setup, both hit modes, both depths
  // The score counts those cells, ours faster where the fps beat the seed's.
  int faster = 0;
  for (const auto& c : j["cells"])
    if (c.contains("seed000_gpu_fps") && c["fps"].get<double>() > c["seed000_gpu_fps"].get<double>()) ++faster;
  const nlohmann::json& score = j["seed000_score"];
  EXPECT_EQ(score["cells"], 4) << score.dump();
  EXPECT_EQ(score["cubes_cells"], 2) << score.dump();
  EXPECT_EQ(score["contours_cells"], 2) << score.dump();
  EXPECT_EQ(score["faster"], faster) << score.dump();
  EXPECT_EQ(score["cubes_faster"].get<int>() + score["contours_faster"].get<int>(), faster) << score.dump();
  EXPECT_EQ(score["camera_outside_voxels_cells"], 4) << score.dump();  // the water camera is above the pool
  EXPECT_EQ(score["camera_outside_voxels_faster"], faster) << score.dump();
}

TEST_F(Cli, RenderTracesVoxelsWithEveryVoxelStructure) {
  const fs::path obj = write("quad.obj", kQuadObj);
  for (const char* accel : {"svo", "grid"}) {
    const fs::path png = dir_ / (std::string(accel) + ".png");
    const RunResult r = run_cli("render '" + obj.string() + "' --accel " + accel +
                                    " --depth 4 --voxel-mode contours --width 24 --height 16 -o '" + png.string() + "'",
                                dir_);
    ASSERT_EQ(r.exit_code, 0) << accel << ": " << r.err;
    EXPECT_NE(r.out.find("voxelize"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find(std::string("(") + accel + ", contours hits"), std::string::npos) << r.out;
    EXPECT_TRUE(fs::exists(png)) << accel;
  }
  const RunResult bad = run_cli("render '" + obj.string() + "' --accel svo --depth 40", dir_);
  EXPECT_NE(bad.exit_code, 0);
  const RunResult mode = run_cli("render '" + obj.string() + "' --accel svo --voxel-mode spheres", dir_);
  EXPECT_NE(mode.exit_code, 0);
  const RunResult lod = run_cli("render '" + obj.string() + "' --accel grid --lod 2", dir_);
  EXPECT_NE(lod.exit_code, 0);
  EXPECT_NE(lod.err.find("--lod needs --accel svo"), std::string::npos) << lod.err;
  EXPECT_NE(run_cli("render '" + obj.string() + "' --accel bvh --voxel-mode contours", dir_).exit_code, 0);
}

// An option of one acceleration structure given with another (or with an .svo file) would
// change nothing: it is refused, before the scene is loaded, rather than ignored.
TEST_F(Cli, OptionsOfAnotherStructureAreRefused) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const fs::path svo = dir_ / "quad.svo";
  ASSERT_EQ(run_cli("voxelize '" + obj.string() + "' --depth 3 -o '" + svo.string() + "'", dir_).exit_code, 0);
  const std::string m = " '" + obj.string() + "'", f = " '" + svo.string() + "'";
  const std::string img = " --width 8 --height 8 -o '" + (dir_ / "x.png").string() + "'";
  for (const auto& [args, message] : std::vector<std::pair<std::string, std::string>>{
           {"render" + m + " --accel svo --bvh-kernel sse4", "--bvh-kernel applies to --accel bvh, not 'svo'"},
           {"render" + m + " --accel grid --max-leaf 4", "--max-leaf applies to --accel bvh, not 'grid'"},
           {"render" + m + " --accel brute --bvh-quality high", "--bvh-quality applies to --accel bvh, not 'brute'"},
           {"render" + m + " --depth 5", "--depth applies to --accel svo|grid, not 'bvh'"},
           {"render" + m + " --voxel-mode cubes", "--voxel-mode applies to --accel svo|grid, not 'bvh'"},
           {"render" + m + " --lod 1", "--lod applies to --accel svo, not 'bvh'"},
           {"render" + m + " --memory-limit 1G", "--memory-limit applies to --accel svo|grid, not 'bvh'"},
           {"render" + m + " --accel svo --max-grid-memory 1G", "--max-grid-memory applies to --accel grid, not 'svo'"},
           {"render" + f + " --depth 5", "is voxelized already"},
           {"render" + f + " --bins 8", "is traced by its octree"},
           {"bench render --sizes 8x8 --scene" + m + " --accel svo --bins 8", "--bins applies to --accel bvh, not 'svo'"}}) {
    const RunResult r = run_cli(args + (args.rfind("bench", 0) == 0 ? "" : img), dir_);
    EXPECT_EQ(r.exit_code, 1) << args;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << "\n" << r.err;
    EXPECT_EQ(r.out.find("load"), std::string::npos) << args << "\n" << r.out;
  }
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
  // Each with its own structure is taken.
  EXPECT_EQ(run_cli("render" + m + " --bvh-kernel sse4 --bvh-quality high --max-leaf 4" + img, dir_).exit_code, 0);
  EXPECT_EQ(run_cli("render" + m + " --accel grid --depth 4 --max-grid-memory 1G --memory-limit 1G" + img, dir_).exit_code, 0);
  EXPECT_EQ(run_cli("render" + f + " --voxel-mode contours --lod 2" + img, dir_).exit_code, 0);
}

TEST_F(Cli, VoxelizeToSvoThenRenderTheFile) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const fs::path svo = dir_ / "quad.svo", png = dir_ / "quad.png";
  const RunResult v = run_cli("voxelize '" + obj.string() + "' --depth 5 -o '" + svo.string() + "'", dir_);
  ASSERT_EQ(v.exit_code, 0) << v.err;
  EXPECT_NE(v.out.find("bytes/voxel"), std::string::npos) << v.out;
  ASSERT_TRUE(fs::exists(svo));
  const RunResult r = run_cli("render '" + svo.string() + "' --width 32 --height 24 -o '" + png.string() + "'", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("voxels at depth 5"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(png));
  // A .svo file is traced by its octree only; a corrupted one is a clear error.
  EXPECT_NE(run_cli("render '" + svo.string() + "' --accel grid -o '" + png.string() + "'", dir_).exit_code, 0);
  const fs::path bad = write("bad.svo", "SVO? not really an octree");
  const RunResult b = run_cli("render '" + bad.string() + "' -o '" + png.string() + "'", dir_);
  EXPECT_EQ(b.exit_code, 1);
  EXPECT_NE(b.err.find("bad.svo"), std::string::npos) << b.err;
  // info describes the file; the commands that need triangles say which ones take it.
  const RunResult i = run_cli("info '" + svo.string() + "'", dir_);
  ASSERT_EQ(i.exit_code, 0) << i.err;
  EXPECT_NE(i.out.find("depth      5  (32^3 voxels"), std::string::npos) << i.out;
  EXPECT_NE(i.out.find("voxels     "), std::string::npos) << i.out;
  EXPECT_NE(i.out.find("bytes/voxel"), std::string::npos) << i.out;
  const RunResult ib = run_cli("info '" + bad.string() + "'", dir_);
  EXPECT_EQ(ib.exit_code, 1);
  EXPECT_NE(ib.err.find("bad.svo"), std::string::npos) << ib.err;
  const fs::path rays = write("rays.txt", "0 0 1 0 0 -1\n");
  for (const std::string& cmd : {"trace '" + svo.string() + "' --rays '" + rays.string() + "'",
                                 "voxelize '" + svo.string() + "' --depth 3", "bench trace --mesh '" + svo.string() + "'",
                                 "bench svo --scene '" + svo.string() + "' --sizes 8x8 --frames 1",
                                 // --accel names a structure the file cannot be traced with (bvh is the
                                 // default, so it was silently ignored when given)
                                 "render '" + svo.string() + "' --accel bvh -o '" + png.string() + "'",
                                 "bench render --scene '" + svo.string() + "' --accel bvh --sizes 8x8 --frames 1"}) {
    const RunResult t = run_cli(cmd, dir_);
    EXPECT_EQ(t.exit_code, 1) << cmd;
    EXPECT_NE(t.err.find("holds voxels, not triangles"), std::string::npos) << cmd << "\n" << t.err;
    EXPECT_EQ(t.out.find("bench svo:"), std::string::npos) << cmd << ": refused after starting\n" << t.out;
  }
  // bench render names what it times: the file's octree, not the default 'bvh'.
  const RunResult br = run_cli("bench render --scene '" + svo.string() + "' --sizes 8x8 --frames 1", dir_);
  ASSERT_EQ(br.exit_code, 0) << br.err;
  EXPECT_NE(br.out.find(", svo depth 5 cubes (file), "), std::string::npos) << br.out;
}

TEST_F(Cli, BenchSvoPrintsSeedTablesContourCostAndPsnr) {
  const RunResult r = run_cli("bench svo --cameras water --sizes 16x12 --depths 2,3 --frames 1", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* want : {"fps, voxel cubes", "fps, contours", "contour cost", "PSNR (dB) of the cube render",
                           "water (16x12)", "depth 2:", "depth 3:"})
    EXPECT_NE(r.out.find(want), std::string::npos) << want << "\n" << r.out;
  // No seed figure at 16x12: no score line. At 640x480 the seed has one per depth and hit mode.
  EXPECT_EQ(r.out.find("faster than seed 000's GPU"), std::string::npos) << r.out;
  const RunResult s = run_cli("bench svo --cameras water --sizes 640x480 --depths 3 --frames 1", dir_);
  ASSERT_EQ(s.exit_code, 0) << s.err;
  const size_t at = s.out.find("faster than seed 000's GPU in ");
  ASSERT_NE(at, std::string::npos) << s.out;
  EXPECT_NE(s.out.find(" of 2 cells (cubes ", at), std::string::npos) << s.out;
  EXPECT_NE(s.out.find("with the camera outside the voxels, ", at), std::string::npos) << s.out;
  EXPECT_NE(run_cli("bench svo --depths 0", dir_).exit_code, 0);
}

// An entry listed twice in --cameras, --sizes or --depths would be measured and printed twice:
// refused before the scene is loaded, naming the entry (and how it was first written).
TEST_F(Cli, BenchListsRefuseRepeatedEntries) {
  for (const auto& [cmd, want] : std::vector<std::pair<std::string, std::string>>{
           {"bench render --cameras water,bunny,water --sizes 8x8 --frames 1", "--cameras: 'water' is listed twice"},
           {"bench render --sizes 8x8,16x12,8x8 --frames 1", "--sizes: '8x8' is listed twice"},
           {"bench render --sizes 8x8,08x8 --frames 1", "--sizes: '08x8' is listed twice (as '8x8')"},
           {"bench svo --depths 3,4,3 --sizes 8x8 --frames 1", "--depths: '3' is listed twice"},
           {"bench svo --depths 3,03 --sizes 8x8 --frames 1", "--depths: '03' is listed twice (as '3')"},
           {"bench svo --cameras bunny,bunny --depths 3 --sizes 8x8 --frames 1", "--cameras: 'bunny' is listed twice"}}) {
    const RunResult r = run_cli(cmd, dir_);
    EXPECT_EQ(r.exit_code, 1) << cmd;
    EXPECT_NE(r.err.find(want), std::string::npos) << cmd << "\n" << r.err;
    EXPECT_EQ(r.out.find("load"), std::string::npos) << cmd << ": refused after loading\n" << r.out;
  }
}

// ---------------------------------------------------------------------------------------------
// Input limits (docs/SECURITY.md, "Limits"): each flag lowers a limit until a small input is
// refused with a message naming the file, the value, the limit and the flag; the default or a
// raised value accepts it; a malformed value is a usage error (exit 2) naming the flag.

TEST_F(Cli, MaxElementsFlag) {
  const fs::path obj = write("quad.obj", kQuadObj);  // 4 vertices, 6 indices
  const RunResult low = run_cli("info '" + obj.string() + "' --max-elements 5", dir_);
  EXPECT_EQ(low.exit_code, 1);
  EXPECT_NE(low.err.find("quad.obj: 6 triangle indices, over the limit of 5 (about 32 bytes of scene memory; "
                         "--max-elements raises the limit)"),
            std::string::npos)
      << low.err;
  EXPECT_EQ(run_cli("info '" + obj.string() + "' --max-elements 6", dir_).exit_code, 0);
  EXPECT_EQ(run_cli("info '" + obj.string() + "' --max-elements 4294967280", dir_).exit_code, 0);
  for (const char* bad : {"0", "-1", "1e9", "4294967281", "99999999999999999999", "99999999999999999999999", "lots"}) {
    const RunResult r = run_cli("info '" + obj.string() + "' --max-elements " + bad, dir_);
    EXPECT_EQ(r.exit_code, 2) << bad;
    EXPECT_NE(r.err.find("--max-elements"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("4294967280"), std::string::npos) << r.err;
  }
}

TEST_F(Cli, MaxFileSizeFlag) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const std::string size = std::to_string(fs::file_size(obj));
  const RunResult low = run_cli("info '" + obj.string() + "' --max-file-size 10", dir_);
  EXPECT_EQ(low.exit_code, 1);
  EXPECT_NE(low.err.find("quad.obj: file is " + size + " bytes, over the limit of 10 bytes (--max-file-size raises it)"),
            std::string::npos)
      << low.err;
  EXPECT_EQ(run_cli("info '" + obj.string() + "' --max-file-size " + size, dir_).exit_code, 0);
  EXPECT_EQ(run_cli("info '" + obj.string() + "' --max-file-size 1KiB", dir_).exit_code, 0);
  EXPECT_EQ(run_cli("info '" + obj.string() + "' --max-file-size 64GiB", dir_).exit_code, 0);
  // Ray files and .svo files, which the scene loaders do not read, get the same limit.
  std::string ray_lines;
  for (int i = 0; i < 10; ++i) ray_lines += "0.25 0.25 1 0 0 -1\n";
  const fs::path rays = write("rays.txt", ray_lines);  // 190 bytes; the OBJ has 46
  const RunResult t = run_cli("trace '" + obj.string() + "' --rays '" + rays.string() + "' --max-file-size 100", dir_);
  EXPECT_EQ(t.exit_code, 1);
  EXPECT_NE(t.err.find("rays.txt: file is"), std::string::npos) << t.err;
  const fs::path svo = dir_ / "quad.svo";
  ASSERT_EQ(run_cli("voxelize '" + obj.string() + "' --depth 3 -o '" + svo.string() + "'", dir_).exit_code, 0);
  const RunResult s = run_cli("render '" + svo.string() + "' --width 8 --height 6 --max-file-size 100 -o '" +
                                  (dir_ / "s.png").string() + "'",
                              dir_);
  EXPECT_EQ(s.exit_code, 1);
  EXPECT_NE(s.err.find("quad.svo: file is"), std::string::npos) << s.err;
  EXPECT_NE(s.err.find("--max-file-size"), std::string::npos) << s.err;
  EXPECT_FALSE(fs::exists(dir_ / "s.png"));
  for (const char* bad : {"0", "-5", "8XB", "1e9", "GiB", "99999999999999999999T"}) {
    const RunResult r = run_cli("info '" + obj.string() + "' --max-file-size " + bad, dir_);
    EXPECT_EQ(r.exit_code, 2) << bad;
    EXPECT_NE(r.err.find("--max-file-size"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("powers of 1024"), std::string::npos) << r.err;
  }
}

TEST_F(Cli, MaxImageMemoryFlag) {
  specula::write_png((dir_ / "sky.png").string(), 4, 2, std::vector<specula::Vec3>(8, specula::Vec3{0.2f, 0.4f, 0.8f}));
  write("quad.obj", kQuadObj);
  const fs::path json = write("sky.json", R"({"meshes": [{"file": "quad.obj"}], "sky": {"type": "image", "image": "sky.png"}})");
  const RunResult low = run_cli("info '" + json.string() + "' --max-image-memory 100", dir_);
  EXPECT_EQ(low.exit_code, 1);
  EXPECT_NE(low.err.find("sky.png: 4x2 image needs about 128 bytes to decode, over the limit of 100 bytes "
                         "(--max-image-memory raises it)"),
            std::string::npos)
      << low.err;
  EXPECT_EQ(run_cli("info '" + json.string() + "' --max-image-memory 1k", dir_).exit_code, 0);
  EXPECT_EQ(run_cli("info '" + json.string() + "'", dir_).exit_code, 0);
  EXPECT_EQ(run_cli("info '" + json.string() + "' --max-image-memory plenty", dir_).exit_code, 2);
}

TEST_F(Cli, MaxGridMemoryFlag) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const std::string base = "render '" + obj.string() + "' --accel grid --depth 6 --width 8 --height 6 -o '" +
                           (dir_ / "g.png").string() + "'";
  const RunResult low = run_cli(base + " --max-grid-memory 1KiB", dir_);  // depth 6: 512 bricks of 4 bytes
  EXPECT_EQ(low.exit_code, 1);
  EXPECT_NE(low.err.find("--accel grid --depth 6: the voxel grid's brick table needs 2 KiB, over the limit of 1 KiB "
                         "(--max-grid-memory raises it"),
            std::string::npos)
      << low.err;
  EXPECT_FALSE(fs::exists(dir_ / "g.png"));
  EXPECT_EQ(run_cli(base + " --max-grid-memory 32KiB", dir_).exit_code, 0);
  EXPECT_EQ(run_cli(base + " --max-grid-memory 1x", dir_).exit_code, 2);
}

// ---------------------------------------------------------------------------------------------
// Interrupted runs (Ctrl-C): the CLI stops at once, removes the temporary file of a write in
// progress and exits with 128 + the signal; the old output stays byte for byte, no temporary
// file remains.

namespace {

/// A CLI child started with posix_spawn (so the test can signal it), stdout and stderr going
/// to files in \p dir, \p env added to the environment.
struct Child {
  pid_t pid = -1;
  fs::path err_path;

  Child(const std::vector<std::string>& args, const fs::path& dir, const std::vector<std::string>& env = {}) {
    err_path = dir / "child.err";
    std::vector<std::string> argv_s{SPECULA_CLI_PATH};
    argv_s.insert(argv_s.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (std::string& a : argv_s) argv.push_back(a.data());
    argv.push_back(nullptr);
    std::vector<std::string> env_s = env;
    for (char** e = environ; *e != nullptr; ++e) env_s.emplace_back(*e);
    std::vector<char*> envp;
    for (std::string& e : env_s) envp.push_back(e.data());
    envp.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&fa, 1, (dir / "child.out").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), envp.data()) != 0) pid = -1;
    posix_spawn_file_actions_destroy(&fa);
  }
  /// Waits up to \p seconds; returns the wait status, or -1 after killing a child that hung.
  int wait(double seconds) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    int status = 0;
    while (std::chrono::steady_clock::now() < end) {
      if (waitpid(pid, &status, WNOHANG) == pid) return status;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    kill(pid, SIGKILL);
    waitpid(pid, &status, 0);
    return -1;
  }
};

/// Names in \p dir other than the child's stdout / stderr captures.
std::vector<std::string> outputs_in(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (n != "child.out" && n != "child.err") names.push_back(n);
  }
  std::sort(names.begin(), names.end());
  return names;
}

bool has_temp_file(const fs::path& dir) {
  for (const std::string& n : outputs_in(dir))
    if (n.find(".tmp-") != std::string::npos) return true;
  return false;
}

}  // namespace

TEST_F(Cli, InterruptedRenderLeavesTheOldOutput) {
  const std::string old_bytes = "the previous image, byte for byte\n";
  const fs::path out = write("out.png", old_bytes);
  for (const int sig : {SIGINT, SIGTERM}) {
    // 4000x3000 takes over a minute on one core: the signal lands while rendering.
    Child child({"render", "cornell", "--width", "4000", "--height", "3000", "--aov", "depth", "-o", out.string()}, dir_);
    ASSERT_GT(child.pid, 0);
    std::this_thread::sleep_for(std::chrono::milliseconds(1500));
    ASSERT_EQ(kill(child.pid, sig), 0);
    const int status = child.wait(60);
    ASSERT_NE(status, -1) << "did not stop on signal " << sig;
    ASSERT_TRUE(WIFEXITED(status)) << "status " << status;
    EXPECT_EQ(WEXITSTATUS(status), 128 + sig);
    const std::string err = slurp(child.err_path);
    EXPECT_NE(err.find(sig == SIGINT ? "interrupted (SIGINT)" : "interrupted (SIGTERM)"), std::string::npos) << err;
    EXPECT_EQ(slurp(out), old_bytes);
    EXPECT_EQ(outputs_in(dir_), std::vector<std::string>{"out.png"});
  }
}

TEST_F(Cli, InterruptedWriteRemovesItsTemporaryFile) {
  // The test hook holds every atomic write between its complete temporary file and the rename:
  // the signal lands while the temporary file exists.
  const std::string old_bytes = "the previous image, byte for byte\n";
  const fs::path out = write("out.png", old_bytes);
  Child child({"render", "cornell", "--width", "64", "--height", "48", "-o", out.string()}, dir_,
              {"SPECULA_TEST_WRITE_DELAY_MS=30000"});
  ASSERT_GT(child.pid, 0);
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (!has_temp_file(dir_) && std::chrono::steady_clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_TRUE(has_temp_file(dir_)) << "no temporary file appeared";
  ASSERT_EQ(kill(child.pid, SIGINT), 0);
  const int status = child.wait(30);
  ASSERT_NE(status, -1) << "did not stop on SIGINT";
  ASSERT_TRUE(WIFEXITED(status)) << "status " << status;
  EXPECT_EQ(WEXITSTATUS(status), 130);
  EXPECT_EQ(slurp(out), old_bytes);
  EXPECT_EQ(outputs_in(dir_), std::vector<std::string>{"out.png"});
}
