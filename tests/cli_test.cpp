// End-to-end tests of the specula command-line tool: exit codes, messages, output files.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

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

TEST_F(Cli, BadOptionsAreUsageErrors) {
  EXPECT_NE(run_cli("render cornell --accel octree", dir_).exit_code, 0);
  EXPECT_NE(run_cli("render cornell --width 0", dir_).exit_code, 0);
  EXPECT_NE(run_cli("render cornell --width 100000", dir_).exit_code, 0);
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

TEST_F(Cli, InfoDescribesAMesh) {
  const fs::path obj = write("quad.obj", kQuadObj);
  const RunResult r = run_cli("info '" + obj.string() + "'", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("triangles  2"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("bounds     [-1 -1 0] - [1 1 0]"), std::string::npos) << r.out;
}

TEST_F(Cli, BenchTraceJsonHasEveryRayKindAndTheKernel) {
  const RunResult r = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --bvh-kernel sse4 --json", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  nlohmann::json j;
  ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
  EXPECT_EQ(j["triangles"].get<int>() > 0, true);
  EXPECT_EQ(j["bvh"]["kernel"], "sse4");
  EXPECT_GT(j["bvh"]["sah_cost"].get<double>(), 0.0);
  std::vector<std::string> kinds;
  for (const auto& k : j["results"]) {
    kinds.push_back(k["kind"].get<std::string>());
    EXPECT_GT(k["count"].get<int>(), 0) << k.dump();
    EXPECT_GT(k["specula_1t"].get<double>(), 0.0) << k.dump();
    EXPECT_GT(k["specula_nt"].get<double>(), 0.0) << k.dump();
    if (j["embree"].get<bool>()) {
      EXPECT_GT(k["ratio_1t"].get<double>(), 0.0) << k.dump();
    }
  }
  EXPECT_EQ(kinds, (std::vector<std::string>{"build", "primary", "shadow", "reflection", "refraction", "diffuse", "random"}));
  // The table names the same kinds.
  const RunResult t = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree", dir_);
  ASSERT_EQ(t.exit_code, 0) << t.err;
  for (const char* k : {"primary", "shadow", "reflection", "refraction", "diffuse", "random"})
    EXPECT_NE(t.out.find(std::string("\n") + k + " "), std::string::npos) << k << "\n" << t.out;
  EXPECT_NE(run_cli("bench trace --scene cornell --bvh-kernel avx9", dir_).exit_code, 0);
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
}

TEST_F(Cli, BenchSvoPrintsSeedTablesContourCostAndPsnr) {
  const RunResult r = run_cli("bench svo --cameras water --sizes 16x12 --depths 2,3 --frames 1", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* want : {"fps, voxel cubes", "fps, contours", "contour cost", "PSNR (dB) of the cube render",
                           "water (16x12)", "depth 2:", "depth 3:"})
    EXPECT_NE(r.out.find(want), std::string::npos) << want << "\n" << r.out;
  EXPECT_NE(run_cli("bench svo --depths 0", dir_).exit_code, 0);
}
