// `specula voxelize`: exact sparse surface voxelization of a scene (seed 000, chapter 1.4.1),
// its statistics, the occupied voxels as text, and seed 000's build-time table.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <string>
#include <tuple>
#include <vector>

#include "commands.h"
#include "core/format.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"
#include "specula/timer.h"
#include "specula/svo.h"
#include "specula/voxelize.h"

namespace specula::cli {
namespace {

VoxelStrategy parse_strategy(const VoxelizeCommandOptions& o) {
  VoxelStrategy s;
  s.plane = false;
  s.sat = false;
  size_t start = 0;
  while (start <= o.tests.size()) {
    const size_t comma = std::min(o.tests.find(',', start), o.tests.size());
    std::string name = o.tests.substr(start, comma - start);
    name.erase(0, name.find_first_not_of(" \t"));
    name.erase(name.find_last_not_of(" \t") + 1);
    if (name == "plane")
      s.plane = true;
    else if (name == "sat")
      s.sat = true;
    else if (name != "aabb" && !name.empty())
      throw Error("--tests: unknown test '" + name + "' (expected a comma-separated list of aabb, plane, sat)");
    start = comma + 1;
  }
  s.sat_at = o.sat_at == "all" ? SatLevel::All : SatLevel::Leaf;
  if (o.traversal.empty())
    s.traversal = s.sat_at == SatLevel::All ? VoxelTraversal::Octree : VoxelTraversal::Range;
  else
    s.traversal = o.traversal == "octree" ? VoxelTraversal::Octree : VoxelTraversal::Range;
  s.vertex_shortcut = o.vertex_shortcut;
  s.clip_shortcut = o.clip_shortcut;
  return s;
}

/// The occupied voxels as "x y z" lines, sorted by x, then y, then z.
std::string xyz_text(const VoxelSet& set) {
  std::vector<std::array<uint32_t, 3>> v(set.codes.size());
  for (size_t i = 0; i < set.codes.size(); ++i) morton_decode(set.codes[i], v[i][0], v[i][1], v[i][2]);
  std::sort(v.begin(), v.end());
  std::string out;
  out.reserve(v.size() * 16);
  char buf[48];
  for (const auto& p : v) {
    const int n = std::snprintf(buf, sizeof buf, "%u %u %u\n", p[0], p[1], p[2]);
    out.append(buf, static_cast<size_t>(n));
  }
  return out;
}

/// The refusal of voxel output \p path, whose extension \p ext is neither .xyz nor .svo.
Error unsupported_output(const std::string& path, const std::string& ext) {
  if (ext.empty())
    return Error(path + ": the output's extension chooses its format, and it has none: name it FILE.xyz (voxel "
                 "coordinates) or FILE.svo (the octree)");
  return Error(path + ": unsupported voxel output '" + ext + "' (supported: .xyz, .svo)");
}

/// Writes \p set to \p path, the format chosen by the extension: .xyz (voxel coordinates as
/// text) or .svo (the sparse voxel octree with its attributes, see docs/svo-format.md).
void write_voxels(const std::string& path, const VoxelSet& set, const SparseVoxelOctree* built,
                  const std::string& protect) {
  const std::string ext = std::filesystem::path(path).extension().string();
  if (ext == ".xyz") {
    const std::string text = xyz_text(set);
    write_file_atomic(path, std::span(reinterpret_cast<const uint8_t*>(text.data()), text.size()), protect);
    return;
  }
  if (ext == ".svo") {
    // voxelize() refuses .svo output without attributes before the load, so the octree is built.
    if (built == nullptr) throw Error(path + ": no octree to write (voxelized without attributes)");
    write_file_atomic(path, svo_to_bytes(*built), protect);
    return;
  }
  throw unsupported_output(path, ext);
}

struct Loaded {
  Scene scene;
  std::vector<TriangleAttributes> attrs;
  double load_ms = 0;
  VoxelizeInput input() const { return {scene.positions, scene.indices, attrs}; }
};

Loaded load(const VoxelizeCommandOptions& o) {
  refuse_octree_input(o.scene, "voxelize");
  Loaded l;
  Timer t;
  l.scene = load_scene(o.scene, o.load);
  l.attrs = triangle_attributes(l.scene);
  l.load_ms = t.ms();
  return l;
}

VoxelizeOptions base_options(const VoxelizeCommandOptions& o, const Scene& scene) {
  VoxelizeOptions v;
  v.threads = o.threads;
  v.attributes = o.attributes;
  v.memory_limit = o.no_memory_limit ? std::numeric_limits<uint64_t>::max() : o.memory_limit;
  v.bounds = scene.bounds();  // the scene's grid (VoxelGrid::around(scene bounds, D))
  return v;
}

// Seed 000, section 1.5: build times in seconds for depths 1-8 (single-threaded C++, 2015).
struct SeedRow {
  const char* name;
  VoxelStrategy strategy;
  std::array<double, 8> seed_s;  ///< negative: no figure in the seed
};

std::vector<SeedRow> table_rows() {
  auto make = [](bool plane, bool sat, SatLevel at, bool shortcut, VoxelTraversal tr) {
    VoxelStrategy s;
    s.plane = plane;
    s.sat = sat;
    s.sat_at = at;
    s.vertex_shortcut = shortcut;
    s.traversal = tr;
    return s;
  };
  constexpr auto O = VoxelTraversal::Octree;
  constexpr std::array<double, 8> none{-1, -1, -1, -1, -1, -1, -1, -1};
  return {
      {"AABB only", make(false, false, SatLevel::Leaf, false, O), none},
      {"AABB + Plane", make(true, false, SatLevel::Leaf, false, O), {3.071, 1.216, 1.185, 1.249, 1.647, 3.335, 17.35, 54.17}},
      {"AABB + Plane + SAT", make(true, true, SatLevel::All, false, O), {23.81, 36.13, 45.40, 54.40, 66.21, 95.46, 197.3, 472.2}},
      {"SAT (leaf level)", make(false, true, SatLevel::Leaf, false, O), {36.25, 14.83, 9.539, 9.960, 13.85, 78.06, 191.2, 427.7}},
      {"Plane + SAT (leaf level)", make(true, true, SatLevel::Leaf, false, O), {34.60, 14.13, 8.870, 9.593, 14.52, 80.69, 204.7, 493.1}},
      {"SAT (leaf) + vertex shortcut", make(false, true, SatLevel::Leaf, true, O), {1.813, 1.038, 0.859, 1.394, 2.216, 11.71, 61.2, 256.6}},
      {"fast: bricks + bbox range", make(true, true, SatLevel::Leaf, true, VoxelTraversal::Range), none},
  };
}

/// Voxels of \p a not in \p b (both sorted).
uint64_t count_extra(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b) {
  uint64_t extra = 0;
  size_t j = 0;
  for (uint64_t c : a) {
    while (j < b.size() && b[j] < c) ++j;
    if (j == b.size() || b[j] != c) ++extra;
  }
  return extra;
}

int print_table(const VoxelizeCommandOptions& o) {
  const Loaded l = load(o);
  const int max_depth = o.depth > 0 ? o.depth : 8;
  const std::vector<SeedRow> rows = table_rows();
  const size_t nd = static_cast<size_t>(max_depth);
  std::vector<std::vector<double>> ms(rows.size(), std::vector<double>(nd));
  std::vector<std::vector<uint64_t>> count(rows.size(), std::vector<uint64_t>(nd)), extra = count, missing = count;
  bool all_exact_agree = true;
  int threads = 0;
  for (int d = 1; d <= max_depth; ++d) {
    std::vector<uint64_t> reference;  // the exact set: from the fast strategy
    for (size_t r = rows.size(); r-- > 0;) {
      VoxelizeOptions v = base_options(o, l.scene);
      v.depth = d;
      v.strategy = rows[r].strategy;
      double best = std::numeric_limits<double>::infinity();
      VoxelSet set;
      for (int rep = 0; rep < o.repeat; ++rep) {
        VoxelizeStats st;
        set = voxelize(l.input(), v, &st);
        best = std::min(best, st.ms);
        threads = st.threads;
      }
      const size_t di = static_cast<size_t>(d - 1);
      if (r + 1 == rows.size()) reference = set.codes;
      ms[r][di] = best;
      count[r][di] = set.codes.size();
      extra[r][di] = count_extra(set.codes, reference);
      missing[r][di] = count_extra(reference, set.codes);
      if (rows[r].strategy.exact() && set.codes != reference) all_exact_agree = false;
    }
  }

  std::printf("seed 000 build-time table: %s, %s triangles, %d thread%s, attributes %s, best of %d run%s\n",
              l.scene.name.empty() ? o.scene.c_str() : l.scene.name.c_str(),
              with_thousands(l.scene.triangle_count()).c_str(), threads, threads == 1 ? "" : "s",
              o.attributes ? "on" : "off", o.repeat, o.repeat == 1 ? "" : "s");
  std::printf("ms = ours (load excluded); seed s = seed 000's seconds (2015, one thread, AABB at every level);\n"
              "voxels = occupied voxels; false+ = voxels not in the exact set (exact rows must show 0)\n\n");
  std::printf("%-30s %-7s", "strategy", "depth");
  for (int d = 1; d <= max_depth; ++d) std::printf(" %10d", d);
  std::printf("\n");
  for (size_t r = 0; r < rows.size(); ++r) {
    const bool exact = rows[r].strategy.exact();
    std::printf("%-30s %-7s", rows[r].name, "ms");
    for (size_t d = 0; d < nd; ++d) std::printf(" %10.3f", ms[r][d]);
    std::printf("\n");
    bool any_seed = false;
    for (size_t d = 0; d < nd && d < 8; ++d) any_seed = any_seed || rows[r].seed_s[d] >= 0;
    if (any_seed) {
      std::printf("%-30s %-7s", "", "seed s");
      for (size_t d = 0; d < nd; ++d) {
        if (d < 8 && rows[r].seed_s[d] >= 0)
          std::printf(" %10.4g", rows[r].seed_s[d]);
        else
          std::printf(" %10s", "-");
      }
      std::printf("\n");
    }
    std::printf("%-30s %-7s", exact ? "  (exact)" : "  (inexact)", "voxels");
    for (size_t d = 0; d < nd; ++d) std::printf(" %10s", with_thousands(count[r][d]).c_str());
    std::printf("\n%-30s %-7s", "", "false+");
    for (size_t d = 0; d < nd; ++d) std::printf(" %10s", with_thousands(extra[r][d]).c_str());
    std::printf("\n");
    for (size_t d = 0; d < nd; ++d)
      if (missing[r][d] != 0) {
        std::printf("%-30s %-7s", "", "missed");
        for (size_t e = 0; e < nd; ++e) std::printf(" %10s", with_thousands(missing[r][e]).c_str());
        std::printf("\n");
        all_exact_agree = false;
        break;
      }
  }
  std::printf("\nexact strategies: %s\n",
              all_exact_agree ? "identical voxel sets at every depth" : "DIFFERENT voxel sets (a bug)");
  return all_exact_agree ? 0 : 1;
}

}  // namespace

CLI::App* add_voxelize_command(CLI::App& app, VoxelizeCommandOptions& o) {
  CLI::App* cmd = app.add_subcommand(
      "voxelize",
      "Voxelize SCENE's triangles exactly (every voxel a triangle touches, closed boxes) at depth D and print\n"
      "triangles, voxels, ms, voxels/s and bytes; --format xyz / -o FILE.xyz lists the voxels, -o FILE.svo writes\n"
      "the octree (specula render FILE.svo); --table\n"
      "reproduces seed 000's build-time table (depths 1-8, every test strategy, voxel counts, false positives)");
  cmd->add_option("scene", o.scene,
                  "a built-in scene (pool, glassbox, cornell, city, city:N), a JSON scene, a glTF file or a mesh (.obj/.ply)")
      ->required();
  cmd->add_option("-d,--depth", o.depth,
                  "octree depth D: 2^D voxels per axis over the scene's bounding cube (with --table: the deepest "
                  "row, default 8)")
      ->check(CLI::Range(1, kMaxVoxelDepth));
  CLI::Option* tests = cmd->add_option("--tests", o.tests,
                  "tests deciding occupancy, comma-separated: aabb (always on), plane, sat. Without sat the result "
                  "is inexact (a superset)")
      ->capture_default_str();
  CLI::Option* sat_at = cmd->add_option("--sat-at", o.sat_at, "where SAT runs: leaf (only on leaf voxels) or all (every octree level)")
      ->check(CLI::IsMember({"leaf", "all"}))
      ->capture_default_str();
  CLI::Option* traversal = cmd->add_option("--traversal", o.traversal,
                  "octree: seed 000's descent from the root, tests per level; range: 32^3 bricks, then each "
                  "triangle's bounding-box voxels (default: range, octree with --sat-at all)")
      ->check(CLI::IsMember({"octree", "range"}));
  CLI::Option* no_vertex = cmd->add_flag("!--no-vertex-shortcut", o.vertex_shortcut,
                "do not accept a leaf voxel that contains a triangle vertex without running SAT");
  CLI::Option* no_clip = cmd->add_flag("!--no-clip-shortcut", o.clip_shortcut,
                "run the tests on every candidate voxel, also those the triangle's clipped part (computed for "
                "the attributes) already shows it crosses (same result, slower)");
  cmd->add_flag("!--no-attributes", o.attributes, "occupancy only: skip clipping, averaging and contours");
  cmd->add_option("--threads", o.threads, "worker threads (0 = all cores)")
      ->check(CLI::Range(0, 1024))
      ->capture_default_str();
  CLI::Option* limit = cmd->add_option("--memory-limit", o.memory_limit,
                  "refuse up front when the memory upper bound exceeds this (bytes; suffixes K, M, G, T: "
                  "1024-based); 0 = half the physical memory")
      ->transform(CLI::AsSizeValue(false));
  cmd->add_flag("--no-memory-limit", o.no_memory_limit, "never refuse (the estimate is still printed)")->excludes(limit);
  CLI::Option* table = cmd->add_flag("--table", o.table,
                "print seed 000's build-time table: every strategy at depths 1..D (D = --depth or 8), our ms "
                "beside the seed's seconds, voxel counts and false positives");
  cmd->add_option("--repeat", o.repeat, "runs per measurement; the best time is printed")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  CLI::Option* format = cmd->add_option("--format", o.format,
                  "xyz: print the occupied voxels as 'x y z' lines sorted by x, then y, then z (to stdout, or to "
                  "-o; the summary then goes to stderr)")
      ->check(CLI::IsMember({"xyz"}));
  CLI::Option* output = cmd->add_option("-o,--output", o.output, "write the voxels to FILE: .xyz (coordinates) or .svo (octree, for specula render FILE.svo), atomically");
  // The table runs every strategy itself and writes no voxels: a strategy or an output given
  // with it is a mistake, not something to ignore.
  for (CLI::Option* x : {tests, sat_at, traversal, no_vertex, no_clip, format, output}) table->excludes(x);
  return cmd;
}

int voxelize(const VoxelizeCommandOptions& o) {
  if (o.table) return print_table(o);
  if (o.depth < 1) throw Error("voxelize: --depth D is required (1.." + std::to_string(kMaxVoxelDepth) + ")");
  if (!o.output.empty()) {
    const std::string ext = std::filesystem::path(o.output).extension().string();
    if (ext != ".xyz" && ext != ".svo") throw unsupported_output(o.output, ext);
    if (o.format == "xyz" && ext != ".xyz")
      throw Error("--format xyz with -o " + o.output + ": the file's extension chooses its format (" + ext +
                  "); name it .xyz, or drop --format");
    if (ext == ".svo" && !o.attributes)
      throw Error("--no-attributes with -o " + o.output + ": an octree file holds every voxel's normal, colour and "
                  "contours, which --no-attributes does not compute (a render of it would be flat); write .xyz "
                  "for the occupancy alone, or drop --no-attributes");
    check_output_path(o.output);  // before the load and the voxelization
  }
  const bool xyz_to_stdout = o.format == "xyz" && o.output.empty();
  FILE* info = xyz_to_stdout ? stderr : stdout;

  const Loaded l = load(o);
  VoxelizeOptions v = base_options(o, l.scene);
  v.depth = o.depth;
  v.strategy = parse_strategy(o);

  // With attributes, each run also builds the octree (what the voxels are for, and part of the
  // issue's build time); the run with the best total is reported.
  VoxelizeStats st;
  SvoInfo si;
  VoxelSet set;
  SparseVoxelOctree svo;
  double best = std::numeric_limits<double>::infinity();
  ProgressLine progress("voxelizing");
  v.progress = progress.callback();
  for (int rep = 0; rep < o.repeat; ++rep) {
    VoxelizeStats s;
    SvoInfo i;
    set = voxelize(l.input(), v, &s);
    VoxelTracerOptions to;
    to.threads = o.threads;  // the octree build on the same threads as the voxelizer
    if (v.attributes) svo = SparseVoxelOctree::build(std::move(set), to, &i);  // takes the attributes; codes stay
    if (s.ms + i.build_ms < best) {
      best = s.ms + i.build_ms;
      st = s;
      si = i;
    }
  }

  progress.finish();  // before the summary lines
  // NOLINTNEXTLINE(bugprone-use-after-move): build(VoxelSet&&) takes only the attributes; grid and codes stay
  const VoxelGrid& g = set.grid;
  std::fprintf(info, "scene     %s: %s triangles (loaded in %.2f ms)%s\n",
               l.scene.name.empty() ? o.scene.c_str() : l.scene.name.c_str(), with_thousands(st.triangles).c_str(),
               l.load_ms,
               st.degenerate_triangles ? (", " + with_thousands(st.degenerate_triangles) + " of zero area").c_str() : "");
  std::fprintf(info, "grid      depth %d: %u^3 voxels of side %g, origin (%g %g %g), cube side %g\n", g.depth,
               g.resolution(), static_cast<double>(g.voxel_size()), static_cast<double>(g.origin.x),
               static_cast<double>(g.origin.y), static_cast<double>(g.origin.z), static_cast<double>(g.side));
  std::fprintf(info, "strategy  %s%s\n", v.strategy.describe().c_str(), v.strategy.exact() ? "" : "  [inexact]");
  std::fprintf(info, "voxelize  %9.2f ms  (%d thread%s%s; prepare %.2f, bin %.2f, voxels %.2f ms)\n", st.ms,
               st.threads, st.threads == 1 ? "" : "s",
               o.repeat > 1 ? (", best of " + std::to_string(o.repeat)).c_str() : "", st.prepare_ms, st.bin_ms,
               st.voxel_ms);
  std::fprintf(info, "voxels    %s  (%.2f Mvoxels/s; %s voxel-triangle pairs in %s bricks)\n",
               with_thousands(st.voxels).c_str(), static_cast<double>(st.voxels) / (std::max(st.ms, 1e-9) * 1e3),
               with_thousands(st.pairs).c_str(), with_thousands(st.bricks).c_str());
  std::fprintf(info, "tests     %s aabb candidates, %s plane, %s sat; accepted without tests: %s by the clip "
               "shortcut, %s by the vertex shortcut\n",
               with_thousands(st.aabb_tests).c_str(), with_thousands(st.plane_tests).c_str(),
               with_thousands(st.sat_tests).c_str(), with_thousands(st.clip_accepts).c_str(),
               with_thousands(st.vertex_hits).c_str());
  std::fprintf(info, "bytes     %s  (%.2f MiB; up-front estimate %.2f MiB, limit %.2f MiB)\n",
               with_thousands(st.bytes).c_str(), static_cast<double>(st.bytes) / 1048576.0,
               static_cast<double>(st.estimate_bytes) / 1048576.0, static_cast<double>(st.memory_limit) / 1048576.0);
  if (v.attributes) {
    std::fprintf(info, "octree    %9.2f ms  (%s nodes, %.2f MiB, %.1f bytes/voxel, %.2f of them nodes)\n", si.build_ms,
                 with_thousands(si.nodes).c_str(), static_cast<double>(si.bytes) / 1048576.0, si.bytes_per_voxel,
                 si.node_bytes_per_voxel);
    std::fprintf(info, "total     %9.2f ms  voxelize + octree (%.2f Mvoxels/s)\n", st.ms + si.build_ms,
                 static_cast<double>(st.voxels) / (std::max(st.ms + si.build_ms, 1e-9) * 1e3));
  }

  if (!o.output.empty()) {
    write_voxels(o.output, set, v.attributes ? &svo : nullptr, o.scene);
    std::fprintf(info, "wrote     %s\n", o.output.c_str());
  } else if (xyz_to_stdout) {
    const std::string text = xyz_text(set);
    std::fwrite(text.data(), 1, text.size(), stdout);
    std::fflush(stdout);
  }
  return 0;
}

}  // namespace specula::cli
