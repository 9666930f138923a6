// The exact sparse voxelizer (include/specula/voxelize.h): strategies agree, a brute-force
// voxelizer agrees, attributes and contours, determinism, limits, bad input, and the CLI.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <atomic>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "specula/error.h"
#include "specula/load.h"
#include "specula/voxelize.h"
#include "test_util.h"
#include "tri_box_reference.h"
#include "cli_test_util.h"

namespace {

using namespace specula;
namespace fs = std::filesystem;

VoxelStrategy strategy(bool plane, bool sat, SatLevel at, bool shortcut, VoxelTraversal tr) {
  VoxelStrategy s;
  s.plane = plane;
  s.sat = sat;
  s.sat_at = at;
  s.vertex_shortcut = shortcut;
  s.traversal = tr;
  return s;
}

/// Every exact strategy (the default plus seed 000's exact rows).
std::vector<VoxelStrategy> exact_strategies() {
  constexpr auto O = VoxelTraversal::Octree, R = VoxelTraversal::Range;
  return {strategy(true, true, SatLevel::Leaf, true, R),   strategy(false, true, SatLevel::Leaf, false, R),
          strategy(true, true, SatLevel::All, false, O),   strategy(false, true, SatLevel::Leaf, false, O),
          strategy(true, true, SatLevel::Leaf, false, O),  strategy(false, true, SatLevel::Leaf, true, O),
          strategy(false, true, SatLevel::All, true, O)};
}

struct Mesh {
  std::vector<Vec3> positions;
  std::vector<uint32_t> indices;
  std::vector<TriangleAttributes> attrs;
  VoxelizeInput input() const { return {positions, indices, attrs}; }
};

/// Random triangles with vertices on a 1/32 lattice of [0,1]^3 (so they touch voxel faces,
/// edges and corners often at depths <= 5), with degenerate and axis-aligned ones mixed in.
Mesh random_mesh(uint64_t seed, int triangles) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> c(0, 32), kind(0, 7);
  Mesh m;
  auto q = [&] { return static_cast<float>(c(rng)) / 32.0f; };
  for (int t = 0; t < triangles; ++t) {
    Vec3 v[3];
    for (Vec3& p : v) p = {q(), q(), q()};
    switch (kind(rng)) {
      case 0: v[1] = v[2] = v[0]; break;                       // point
      case 1: v[2] = v[1]; break;                              // segment
      case 2: v[2] = v[0] + (v[1] - v[0]) * 0.5f; break;       // collinear (1/64 lattice, still exact)
      case 3: v[1].z = v[2].z = v[0].z; break;                 // axis-aligned
      default: break;
    }
    for (const Vec3& p : v) {
      m.indices.push_back(static_cast<uint32_t>(m.positions.size()));
      m.positions.push_back(p);
    }
  }
  return m;
}

/// Brute force: for each triangle, every voxel of its bounding box (one voxel of margin),
/// tested with the exact reference. Valid when the grid is [0,1]^3 and vertices are dyadic,
/// so the lattice coordinates are p * 2^29 exactly.
std::vector<uint64_t> brute_force(const Mesh& m, int depth) {
  const int64_t side = voxel::kLatticeSide;
  const int64_t size = side >> depth;
  const int64_t res = int64_t{1} << depth;
  std::set<uint64_t> out;
  for (size_t t = 0; t < m.indices.size() / 3; ++t) {
    int64_t v[3][3];
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k)
        v[i][k] = static_cast<int64_t>(static_cast<double>(m.positions[m.indices[3 * t + i]][k]) * static_cast<double>(side));
    int64_t lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::max<int64_t>(0, std::min({v[0][k], v[1][k], v[2][k]}) / size - 1);
      hi[k] = std::min<int64_t>(res - 1, std::max({v[0][k], v[1][k], v[2][k]}) / size + 1);
    }
    for (int64_t z = lo[2]; z <= hi[2]; ++z)
      for (int64_t y = lo[1]; y <= hi[1]; ++y)
        for (int64_t x = lo[0]; x <= hi[0]; ++x)
          if (test::reference_overlap(v, voxel::LatticeBox{{x * size, y * size, z * size}, size}))
            out.insert(morton_encode(static_cast<uint32_t>(x), static_cast<uint32_t>(y), static_cast<uint32_t>(z)));
  }
  return {out.begin(), out.end()};
}

VoxelizeOptions unit_options(int depth) {
  VoxelizeOptions o;
  o.depth = depth;
  o.bounds = Aabb{{0, 0, 0}, {1, 1, 1}};
  return o;
}

bool sorted_unique(const std::vector<uint64_t>& v) {
  for (size_t i = 1; i < v.size(); ++i)
    if (!(v[i - 1] < v[i])) return false;
  return true;
}

TEST(VoxelizeExact, BruteForceAgreesOnRandomMeshes) {
  for (uint64_t seed = 1; seed <= 6; ++seed) {
    const Mesh m = random_mesh(seed, 40);
    for (int depth = 1; depth <= 5; ++depth) {
      const std::vector<uint64_t> ref = brute_force(m, depth);
      for (const VoxelStrategy& s : exact_strategies()) {
        VoxelizeOptions o = unit_options(depth);
        o.strategy = s;
        const VoxelSet set = voxelize(m.input(), o);
        ASSERT_TRUE(sorted_unique(set.codes));
        ASSERT_EQ(set.codes.size(), set.attrs.size());
        ASSERT_EQ(set.codes, ref) << "seed " << seed << " depth " << depth << ": " << s.describe() << " has "
                                  << set.codes.size() << " voxels, brute force " << ref.size();
      }
    }
  }
}

TEST(VoxelizeExact, InexactStrategiesAreSupersets) {
  const Mesh m = random_mesh(42, 200);
  for (int depth = 2; depth <= 6; ++depth) {
    VoxelizeOptions o = unit_options(depth);
    o.attributes = false;
    const std::vector<uint64_t> exact = voxelize(m.input(), o).codes;
    o.strategy = strategy(true, false, SatLevel::Leaf, false, VoxelTraversal::Octree);
    const std::vector<uint64_t> plane = voxelize(m.input(), o).codes;
    o.strategy = strategy(false, false, SatLevel::Leaf, false, VoxelTraversal::Octree);
    const std::vector<uint64_t> aabb = voxelize(m.input(), o).codes;
    o.strategy.traversal = VoxelTraversal::Range;
    EXPECT_EQ(voxelize(m.input(), o).codes, aabb);  // the traversals agree for inexact tests too
    EXPECT_TRUE(std::includes(plane.begin(), plane.end(), exact.begin(), exact.end()));
    EXPECT_TRUE(std::includes(aabb.begin(), aabb.end(), plane.begin(), plane.end()));
    if (depth >= 4) {
      EXPECT_GT(aabb.size(), exact.size());  // the AABB test alone is visibly loose
    }
  }
}

/// Calls body(name, scene) for every shared mesh (loaded quietly); a missing mesh is a failure.
template <class Body>
void for_each_shared_mesh(Body&& body) {
  for (const char* name : test::kSharedMeshes) {
    const fs::path path = test::shared_mesh(name);
    if (path.empty()) {
      ADD_FAILURE() << "shared mesh " << name << " missing from " << test::shared_mesh_dir();
      continue;
    }
    LoadOptions lo;
    lo.warn = [](const std::string&) {};
    body(name, load_scene(path.string(), lo));
  }
}

TEST(VoxelizeExact, AllExactStrategiesAgreeOnSharedMeshes) {
  if (test::shared_mesh_dir().empty())
    GTEST_SKIP() << "shared meshes not found (set SPECULA_DATA or place ../shared/data/meshes beside the source tree)";
  for_each_shared_mesh([](const char* name, const Scene& scene) {
    const VoxelizeInput in{scene.positions, scene.indices, {}};
    for (int depth = 1; depth <= 8; ++depth) {
      VoxelizeOptions o;
      o.depth = depth;
      o.bounds = scene.bounds();
      o.attributes = false;
      const std::vector<uint64_t> ref = voxelize(in, o).codes;
      ASSERT_TRUE(sorted_unique(ref)) << name;
      ASSERT_FALSE(ref.empty()) << name;
      // Every exact strategy at depth <= 6; the seed's fastest exact rows at 7 and 8 (the
      // others run the same tests in the same order of levels, and are covered below 7).
      std::vector<VoxelStrategy> strategies = exact_strategies();
      if (depth >= 7) strategies = {strategies[2], strategies[5]};
      for (const VoxelStrategy& s : strategies) {
        o.strategy = s;
        ASSERT_EQ(voxelize(in, o).codes, ref) << name << " depth " << depth << ": " << s.describe();
      }
    }
  });
}

// The clip shortcut (a voxel whose clipped part lies inside it is accepted without tests) is a
// pure speed-up: with attributes on, every strategy gives the voxels it gives without
// attributes, and switching the shortcut off changes no bit of the result.
TEST(VoxelizeExact, ClipShortcutChangesNothingOnSharedMeshes) {
  if (test::shared_mesh_dir().empty())
    GTEST_SKIP() << "shared meshes not found (set SPECULA_DATA or place ../shared/data/meshes beside the source tree)";
  for_each_shared_mesh([](const char* name, const Scene& scene) {
    const VoxelizeInput in{scene.positions, scene.indices, {}};
    for (const int depth : {3, 6, 8}) {
      for (const VoxelStrategy& base : {VoxelStrategy{}, strategy(false, false, SatLevel::Leaf, false,
                                                                  VoxelTraversal::Range)}) {
        VoxelizeOptions o;
        o.depth = depth;
        o.bounds = scene.bounds();
        o.strategy = base;
        o.attributes = false;
        const std::vector<uint64_t> occupancy = voxelize(in, o).codes;
        o.attributes = true;
        VoxelizeStats with_stats, without_stats;
        const VoxelSet with = voxelize(in, o, &with_stats);
        o.strategy.clip_shortcut = false;
        const VoxelSet without = voxelize(in, o, &without_stats);
        ASSERT_EQ(with.codes, occupancy) << name << " depth " << depth << ": " << base.describe();
        ASSERT_EQ(without.codes, occupancy) << name << " depth " << depth;
        ASSERT_EQ(with.attrs.size(), without.attrs.size());
        EXPECT_EQ(std::memcmp(with.attrs.data(), without.attrs.data(), with.attrs.size() * sizeof(VoxelAttributes)), 0)
            << name << " depth " << depth << ": attributes differ with and without the clip shortcut";
        if (base.exact()) {  // most pairs are certified (the inexact strategy's extra pairs cannot be)
          EXPECT_GT(with_stats.clip_accepts, with_stats.pairs / 2) << name << " depth " << depth;
        }
        EXPECT_EQ(without_stats.clip_accepts, 0u);
      }
    }
  });
}

TEST(VoxelizeAttributes, AxisAlignedQuadNormalContoursAndAreaWeightedColours) {
  // The quad z = 0.3 over [0,1]^2: red triangle (y <= x), blue triangle (y >= x).
  Mesh m;
  m.positions = {{0, 0, 0.3f}, {1, 0, 0.3f}, {1, 1, 0.3f}, {0, 1, 0.3f}};
  m.indices = {0, 1, 2, 0, 2, 3};
  TriangleAttributes red, blue;
  red.colour = {1, 0, 0};
  red.reflectivity = 0.5f;
  red.ior = 1.5f;
  red.material = 7;
  blue.colour = {0, 0, 1};
  blue.transparency = 1.0f;
  blue.ior = 1.0f;
  blue.material = 9;
  m.attrs = {red, blue};
  const int depth = 2;  // 4^3 voxels of side 0.25; z = 0.3 lies in layer z = 1
  const VoxelSet set = voxelize(m.input(), unit_options(depth));
  ASSERT_EQ(set.size(), 16u);
  ASSERT_EQ(set.attrs.size(), 16u);
  const float s = set.grid.voxel_size();
  for (size_t i = 0; i < set.size(); ++i) {
    uint32_t x, y, z;
    morton_decode(set.codes[i], x, y, z);
    EXPECT_EQ(z, 1u);
    const VoxelAttributes& a = set.attrs[i];
    EXPECT_EQ(a.normal, (Vec3{0, 0, 1}));  // exact: both triangles have normal +z
    // Every point of the quad in this voxel: dot(n, p - c) = 0.3 - 0.375.
    const float d = 0.3f - (static_cast<float>(z) + 0.5f) * s;
    EXPECT_LE(a.contour_lo, d);
    EXPECT_GE(a.contour_hi, d);
    EXPECT_LT(a.contour_hi - a.contour_lo, 1e-4f * s);
    if (x > y) {  // entirely on the red side (the blue triangle touches at most a corner: weight 0)
      EXPECT_EQ(a.colour, (Vec3{1, 0, 0})) << x << " " << y;
      EXPECT_EQ(a.material, 7u);
      EXPECT_FLOAT_EQ(a.reflectivity, 0.5f);
      EXPECT_FLOAT_EQ(a.ior, 1.5f);
    } else if (x < y) {
      EXPECT_EQ(a.colour, (Vec3{0, 0, 1})) << x << " " << y;
      EXPECT_EQ(a.material, 9u);
      EXPECT_FLOAT_EQ(a.transparency, 1.0f);
    } else {  // the diagonal splits the voxel into equal halves
      EXPECT_NEAR(a.colour.x, 0.5f, 1e-6f);
      EXPECT_NEAR(a.colour.z, 0.5f, 1e-6f);
      EXPECT_EQ(a.colour.y, 0.0f);
      EXPECT_NEAR(a.reflectivity, 0.25f, 1e-6f);
      EXPECT_NEAR(a.transparency, 0.5f, 1e-6f);
      EXPECT_NEAR(a.ior, 1.25f, 1e-6f);
    }
  }
}

TEST(VoxelizeAttributes, QuadOnAVoxelFaceOccupiesBothLayersAndContoursEncloseIt) {
  // Closed boxes: the quad z = 0.25 touches layers z = 0 and z = 1 at depth 2.
  Mesh m;
  m.positions = {{0, 0, 0.25f}, {1, 0, 0.25f}, {1, 1, 0.25f}, {0, 1, 0.25f}};
  m.indices = {0, 1, 2, 0, 2, 3};
  const VoxelSet set = voxelize(m.input(), unit_options(2));
  ASSERT_EQ(set.size(), 32u);
  const float s = set.grid.voxel_size();
  for (size_t i = 0; i < set.size(); ++i) {
    uint32_t x, y, z;
    morton_decode(set.codes[i], x, y, z);
    const float d = 0.25f - (static_cast<float>(z) + 0.5f) * s;  // +-0.125 (a face of the voxel)
    EXPECT_LE(set.attrs[i].contour_lo, d + 1e-7f);
    EXPECT_GE(set.attrs[i].contour_hi, d - 1e-7f);
  }
}

TEST(VoxelizeAttributes, ContoursEncloseClippedPartsOfATiltedTriangle) {
  Mesh m;
  m.positions = {{0.05f, 0.1f, 0.0f}, {0.9f, 0.2f, 0.7f}, {0.3f, 0.95f, 1.0f}};
  m.indices = {0, 1, 2};
  const VoxelSet set = voxelize(m.input(), unit_options(3));
  ASSERT_GT(set.size(), 10u);
  const Vec3 n = normalize(cross(m.positions[1] - m.positions[0], m.positions[2] - m.positions[0]));
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1);
  // Sample points of the triangle; each lies in some voxel whose contours must hold it.
  int checked = 0;
  for (int i = 0; i < 20000; ++i) {
    float a = u(rng), b = u(rng);
    if (a + b > 1) a = 1 - a, b = 1 - b;
    const Vec3 p = m.positions[0] + (m.positions[1] - m.positions[0]) * a + (m.positions[2] - m.positions[0]) * b;
    const float sz = set.grid.voxel_size();
    const uint32_t x = std::min(7u, static_cast<uint32_t>(p.x / sz)), y = std::min(7u, static_cast<uint32_t>(p.y / sz)),
                   z = std::min(7u, static_cast<uint32_t>(p.z / sz));
    const auto it = std::lower_bound(set.codes.begin(), set.codes.end(), morton_encode(x, y, z));
    ASSERT_TRUE(it != set.codes.end() && *it == morton_encode(x, y, z));
    const VoxelAttributes& va = set.attrs[static_cast<size_t>(it - set.codes.begin())];
    EXPECT_NEAR(dot(va.normal, n), 1.0f, 1e-5f);
    const Vec3 c = Vec3{static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f, static_cast<float>(z) + 0.5f} * sz;
    const float d = dot(va.normal, p - c);
    EXPECT_GE(d, va.contour_lo - 1e-6f);
    EXPECT_LE(d, va.contour_hi + 1e-6f);
    ++checked;
  }
  EXPECT_EQ(checked, 20000);
}

/// The reference for a clipped part: the triangle cut by the closed box's 6 planes in turn
/// (Sutherland-Hodgman in double), written independently of the voxelizer's slab sweeps.
using P3 = std::array<double, 3>;
std::vector<P3> clip_to_box(std::vector<P3> poly, const double lo[3], const double hi[3]) {
  for (int k = 0; k < 3 && !poly.empty(); ++k)
    for (int upper = 0; upper < 2 && !poly.empty(); ++upper) {
      std::vector<P3> out;
      const size_t n = poly.size();
      for (size_t i = 0; i < n; ++i) {
        const P3& a = poly[(i + n - 1) % n];
        const P3& b = poly[i];
        const double da = upper ? hi[k] - a[k] : a[k] - lo[k];  // >= 0 inside
        const double db = upper ? hi[k] - b[k] : b[k] - lo[k];
        if ((da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0)) {
          const double t = da / (da - db);
          out.push_back({a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t});
        }
        if (db >= 0.0) out.push_back(b);
      }
      poly = std::move(out);
    }
  return poly;
}

double polygon_area(const std::vector<P3>& q) {
  double c[3] = {0, 0, 0};
  for (size_t i = 1; i + 1 < q.size(); ++i) {
    const double e0[3] = {q[i][0] - q[0][0], q[i][1] - q[0][1], q[i][2] - q[0][2]};
    const double e1[3] = {q[i + 1][0] - q[0][0], q[i + 1][1] - q[0][1], q[i + 1][2] - q[0][2]};
    c[0] += e0[1] * e1[2] - e0[2] * e1[1];
    c[1] += e0[2] * e1[0] - e0[0] * e1[2];
    c[2] += e0[0] * e1[1] - e0[1] * e1[0];
  }
  return 0.5 * std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
}

/// Clips every pair of \p m's triangles and their bounding boxes' voxels at \p depth on its own
/// in double (clip_to_box) and checks the voxelizer against it: every reference vertex between
/// its voxel's contours, a part of any area in a voxel of the set, and each voxel's colour and
/// normal the averages weighted by the reference areas (so the voxelizer's part areas are
/// right, up to rounding, whatever order it clips in). Returns the set; \p max_part_vertices
/// gets the most vertices of a reference part.
VoxelSet check_against_brute_force_clip(const Mesh& m, int depth, size_t* max_part_vertices = nullptr) {
  const VoxelSet set = voxelize(m.input(), unit_options(depth));
  const double side = set.grid.voxel_size();
  const double origin[3] = {set.grid.origin.x, set.grid.origin.y, set.grid.origin.z};
  const int64_t res = int64_t{1} << depth;
  struct Sums {
    double area = 0, col[3] = {0, 0, 0}, nrm[3] = {0, 0, 0};
    double dmin = std::numeric_limits<double>::infinity(), dmax = -std::numeric_limits<double>::infinity();
  };
  std::vector<Sums> sums(set.size());
  size_t parts = 0, vertices = 0, max_vertices = 0;
  for (size_t t = 0; t < m.indices.size() / 3; ++t) {
    std::vector<P3> tri(3);
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) tri[i][k] = m.positions[m.indices[3 * t + i]][k];
    const double e0[3] = {tri[1][0] - tri[0][0], tri[1][1] - tri[0][1], tri[1][2] - tri[0][2]};
    const double e1[3] = {tri[2][0] - tri[0][0], tri[2][1] - tri[0][1], tri[2][2] - tri[0][2]};
    double n[3] = {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2], e0[0] * e1[1] - e0[1] * e1[0]};
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    EXPECT_GT(len, 0.0);
    for (double& x : n) x /= len;
    int64_t lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
      const double a = std::min({tri[0][k], tri[1][k], tri[2][k]}), b = std::max({tri[0][k], tri[1][k], tri[2][k]});
      lo[k] = std::max<int64_t>(0, static_cast<int64_t>(std::floor((a - origin[k]) / side)) - 1);
      hi[k] = std::min<int64_t>(res - 1, static_cast<int64_t>(std::floor((b - origin[k]) / side)) + 1);
    }
    for (int64_t z = lo[2]; z <= hi[2]; ++z)
      for (int64_t y = lo[1]; y <= hi[1]; ++y)
        for (int64_t x = lo[0]; x <= hi[0]; ++x) {
          const int64_t c[3] = {x, y, z};
          double blo[3], bhi[3];
          for (int k = 0; k < 3; ++k) {
            blo[k] = origin[k] + static_cast<double>(c[k]) * side;
            bhi[k] = blo[k] + side;
          }
          const std::vector<P3> part = clip_to_box(tri, blo, bhi);
          if (part.empty()) continue;
          const double area = polygon_area(part);
          max_vertices = std::max(max_vertices, part.size());
          const uint64_t code = morton_encode(static_cast<uint32_t>(x), static_cast<uint32_t>(y), static_cast<uint32_t>(z));
          const auto it = std::lower_bound(set.codes.begin(), set.codes.end(), code);
          const bool found = it != set.codes.end() && *it == code;
          if (!found) {  // only a touching part (rounding of the snap) may miss the set
            EXPECT_LT(area, 1e-6 * side * side) << "triangle " << t << " voxel " << x << " " << y << " " << z;
            continue;
          }
          const size_t i = static_cast<size_t>(it - set.codes.begin());
          const VoxelAttributes& va = set.attrs[i];
          const double centre[3] = {blo[0] + 0.5 * side, blo[1] + 0.5 * side, blo[2] + 0.5 * side};
          for (const P3& p : part) {
            const double d = va.normal.x * (p[0] - centre[0]) + va.normal.y * (p[1] - centre[1]) + va.normal.z * (p[2] - centre[2]);
            EXPECT_GE(d, va.contour_lo - 1e-6 * side) << "triangle " << t << " voxel " << x << " " << y << " " << z;
            EXPECT_LE(d, va.contour_hi + 1e-6 * side) << "triangle " << t << " voxel " << x << " " << y << " " << z;
            sums[i].dmin = std::min(sums[i].dmin, d);
            sums[i].dmax = std::max(sums[i].dmax, d);
            ++vertices;
          }
          Sums& s = sums[i];
          s.area += area;
          const float* col = &m.attrs[t].colour.x;
          for (int k = 0; k < 3; ++k) {
            s.col[k] += area * col[k];
            s.nrm[k] += area * n[k];
          }
          ++parts;
        }
  }
  EXPECT_GT(vertices, 3 * parts);  // ~4 per part: mostly triangles and quadrilaterals
  if (max_part_vertices) *max_part_vertices = max_vertices;
  size_t weighted = 0;
  for (size_t i = 0; i < set.size(); ++i) {
    const Sums& s = sums[i];
    // Tight as well: no wider than the reference parts and the 1e-5 voxel widening (a contour
    // from a vertex that is not the part's would show here).
    if (s.dmin <= s.dmax) {
      EXPECT_GE(set.attrs[i].contour_lo, s.dmin - 2e-5 * side) << "voxel " << i;
      EXPECT_LE(set.attrs[i].contour_hi, s.dmax + 2e-5 * side) << "voxel " << i;
    }
    if (s.area < 1e-3 * side * side) continue;  // weights of nearly touching parts: rounding decides
    ++weighted;
    const VoxelAttributes& va = set.attrs[i];
    const float* col = &va.colour.x;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(col[k], s.col[k] / s.area, 1e-4) << "voxel " << i;
    const double len = std::sqrt(s.nrm[0] * s.nrm[0] + s.nrm[1] * s.nrm[1] + s.nrm[2] * s.nrm[2]);
    if (len < 0.5 * s.area) continue;  // normals nearly cancel: the direction is ill-conditioned
    const float* nv = &va.normal.x;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(nv[k], s.nrm[k] / len, 1e-4) << "voxel " << i;
  }
  EXPECT_GT(weighted, set.size() / 2);
  return set;
}

TEST(VoxelizeAttributes, ContoursAndAreaWeightsAgreeWithABruteForceClipInDouble) {
  // Tilted triangles with random colours; every (triangle, voxel) pair of each triangle's
  // bounding box is clipped by the reference above. Every reference vertex must lie between
  // its voxel's contours, a part of any area must belong to a voxel of the set, and each
  // voxel's colour and normal must be the averages weighted by the reference areas (so the
  // voxelizer's part areas are right, up to rounding, whatever order it clips in).
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Mesh m;
  for (int t = 0; t < 300; ++t) {
    const Vec3 c{0.1f + 0.8f * u(rng), 0.1f + 0.8f * u(rng), 0.1f + 0.8f * u(rng)};
    for (int i = 0; i < 3; ++i) {
      m.indices.push_back(static_cast<uint32_t>(m.positions.size()));
      m.positions.push_back(c + Vec3{u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f} * 0.2f);
    }
    TriangleAttributes a;
    a.colour = {u(rng), u(rng), u(rng)};
    m.attrs.push_back(a);
  }
  const VoxelSet set = check_against_brute_force_clip(m, 5);
  EXPECT_GT(set.size(), 1000u);
}

TEST(VoxelizeAttributes, PartsWithMoreThanSixVerticesAgreeWithTheBruteForceClip) {
  // Large tilted triangles at depth 3: the plane cuts whole voxels through six faces and the
  // triangle's own edges cut more, so parts with 7 to 9 vertices occur (the most a triangle
  // cut by a cube can have; the polygon buffers, the area fan and the contours must hold them).
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Mesh m;
  for (int t = 0; t < 40; ++t) {
    for (int i = 0; i < 3; ++i) {
      m.indices.push_back(static_cast<uint32_t>(m.positions.size()));
      m.positions.push_back(Vec3{u(rng), u(rng), u(rng)});
    }
    TriangleAttributes a;
    a.colour = {u(rng), u(rng), u(rng)};
    m.attrs.push_back(a);
  }
  size_t most = 0;
  const VoxelSet set = check_against_brute_force_clip(m, 3, &most);
  EXPECT_GT(set.size(), 100u);
  EXPECT_GE(most, 7u);
}

TEST(Voxelize, BitIdenticalForAnyThreadCount) {
  // Many small triangles (a random mesh shrunk around random centres) and the bunny.
  Mesh m = random_mesh(3, 3000);
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<float> centre(0.0f, 0.9f);
  for (size_t t = 0; t < m.positions.size(); t += 3) {
    const Vec3 c{centre(rng), centre(rng), centre(rng)};
    for (size_t i = t; i < t + 3; ++i) m.positions[i] = c + m.positions[i] * 0.1f;
  }
  for (size_t t = 0; t < m.indices.size() / 3; ++t) {
    TriangleAttributes a;
    a.colour = {static_cast<float>(t % 7) / 7.0f, static_cast<float>(t % 5) / 5.0f, 0.3f};
    a.reflectivity = static_cast<float>(t % 3) / 3.0f;
    m.attrs.push_back(a);
  }
  std::vector<Mesh> meshes = {m};
  if (const fs::path p = test::shared_mesh("stanford-bunny.obj"); !p.empty()) {
    const Scene scene = load_scene(p.string());
    Mesh b;
    b.positions = scene.positions;
    b.indices = scene.indices;
    b.attrs = triangle_attributes(scene);
    meshes.push_back(std::move(b));
  }
  for (const Mesh& mesh : meshes) {
    VoxelizeOptions o;
    o.depth = 7;
    o.threads = 1;
    const VoxelSet one = voxelize(mesh.input(), o);
    ASSERT_GT(one.size(), 1000u);
    for (int threads : {2, 4, 7}) {  // 7: more threads than cores, bricks finishing out of order
      o.threads = threads;
      const VoxelSet many = voxelize(mesh.input(), o);
      ASSERT_EQ(many.codes, one.codes) << threads << " threads";
      ASSERT_EQ(many.attrs.size(), one.attrs.size());
      EXPECT_EQ(std::memcmp(many.attrs.data(), one.attrs.data(), one.attrs.size() * sizeof(VoxelAttributes)), 0)
          << threads << " threads: attributes differ";
    }
  }
}

// VoxelizeOptions::progress: called once per brick, from one thread at a time, with fractions
// that rise to exactly 1; the voxels are the same with or without it.
TEST(Voxelize, ProgressRisesToOneOncePerBrick) {
  const Mesh m = random_mesh(5, 400);
  VoxelizeOptions o;
  o.depth = 8;
  o.threads = 4;
  VoxelizeStats st;
  const VoxelSet plain = voxelize(m.input(), o, &st);
  ASSERT_GT(st.bricks, 8u);
  std::vector<double> seen;
  std::atomic<int> inside{0};
  bool overlapped = false;
  o.progress = [&](double f) {
    overlapped |= inside.fetch_add(1) != 0;
    seen.push_back(f);
    inside.fetch_sub(1);
  };
  const VoxelSet reported = voxelize(m.input(), o);
  EXPECT_FALSE(overlapped) << "progress called from two threads at once";
  ASSERT_EQ(seen.size(), st.bricks);
  for (size_t i = 1; i < seen.size(); ++i) EXPECT_GT(seen[i], seen[i - 1]) << i;
  EXPECT_GT(seen.front(), 0.0);
  EXPECT_EQ(seen.back(), 1.0);
  EXPECT_EQ(reported.codes, plain.codes);
  EXPECT_EQ(std::memcmp(reported.attrs.data(), plain.attrs.data(), plain.attrs.size() * sizeof(VoxelAttributes)), 0);
}

/// FNV-1a over the set's codes and attribute bytes.
uint64_t set_hash(const VoxelSet& set) {
  uint64_t h = 1469598103934665603ull;
  auto eat = [&](const void* p, size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ull;
  };
  eat(set.codes.data(), set.codes.size() * sizeof(uint64_t));
  eat(set.attrs.data(), set.attrs.size() * sizeof(VoxelAttributes));
  return h;
}

TEST(Voxelize, AttributeBitsArePinned) {
  // The voxelizer's sums, clipping and contours are specified to the bit (fixed order, no
  // contraction, whatever the target): a speed-up that changes any bit of any attribute fails
  // here. Tilted triangles from a portable generator (no std distributions), with colours, so
  // every weighted sum and the contours depend on every clipped part.
  uint64_t state = 0x9E3779B97F4A7C15ull;
  auto next = [&] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>(static_cast<uint32_t>(state >> 40)) / 16777216.0f;  // [0, 1), exact
  };
  Mesh m;
  for (int t = 0; t < 2000; ++t) {
    const Vec3 c{0.05f + 0.9f * next(), 0.05f + 0.9f * next(), 0.05f + 0.9f * next()};
    for (int i = 0; i < 3; ++i) {
      m.indices.push_back(static_cast<uint32_t>(m.positions.size()));
      m.positions.push_back(c + Vec3{next() - 0.5f, next() - 0.5f, next() - 0.5f} * 0.08f);
    }
    TriangleAttributes a;
    a.colour = {next(), next(), next()};
    a.reflectivity = next();
    a.transparency = next();
    a.ior = 1.0f + next();
    a.material = static_cast<uint32_t>(t % 5);
    m.attrs.push_back(a);
  }
  VoxelizeOptions o = unit_options(6);
  o.threads = 2;
  const VoxelSet set = voxelize(m.input(), o);
  ASSERT_EQ(set.size(), 26990u);
  EXPECT_EQ(set_hash(set), 0xf8c75b294beb337cull) << std::hex << set_hash(set);
}

TEST(Voxelize, MemoryLimitRefusesUpFrontWithAnEstimate) {
  const Mesh m = random_mesh(8, 500);
  VoxelizeOptions o;
  o.depth = kMaxVoxelDepth;  // default limit: half the physical memory, far below the need
  try {
    voxelize(m.input(), o);
    FAIL() << "depth 21 was not refused";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("bytes"), std::string::npos) << msg;
    EXPECT_NE(msg.find("memory limit"), std::string::npos) << msg;
  }
  o.depth = 4;
  o.memory_limit = 1000;
  EXPECT_THROW(voxelize(m.input(), o), Error);
  const uint64_t estimate = voxelize_memory_estimate(m.input(), o);
  EXPECT_GT(estimate, 1000u);
  o.memory_limit = estimate;  // exactly the estimate passes
  VoxelizeStats st;
  const VoxelSet set = voxelize(m.input(), o, &st);
  EXPECT_EQ(st.estimate_bytes, estimate);
  EXPECT_LE(st.bytes, estimate);
  EXPECT_GT(set.size(), 0u);
}

TEST(Voxelize, BadInputIsAClearError) {
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.indices = {0, 1, 2};
  VoxelizeOptions o;
  o.depth = 3;
  EXPECT_NO_THROW(voxelize(m.input(), o));
  auto throws_with = [&](const Mesh& mesh, const VoxelizeOptions& opt, const std::string& text) {
    try {
      voxelize(mesh.input(), opt);
      ADD_FAILURE() << "no error, expected '" << text << "'";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  for (int depth : {0, -1, kMaxVoxelDepth + 1}) {
    VoxelizeOptions bad = o;
    bad.depth = depth;
    throws_with(m, bad, "depth");
  }
  Mesh nan = m;
  nan.positions[1].y = std::nanf("");
  throws_with(nan, o, "not finite");
  Mesh inf = m;
  inf.positions[2].z = kInf;
  throws_with(inf, o, "not finite");
  Mesh out_of_range = m;
  out_of_range.indices[2] = 3;
  throws_with(out_of_range, o, "out of range");
  throws_with(Mesh{}, o, "no triangles");
  Mesh ragged = m;
  ragged.indices.push_back(0);
  throws_with(ragged, o, "multiple of 3");
  VoxelizeOptions all_range = o;
  all_range.strategy.sat_at = SatLevel::All;
  all_range.strategy.traversal = VoxelTraversal::Range;
  throws_with(m, all_range, "octree");
  // A degenerate-only mesh is fine: a point and a segment occupy the voxels they touch.
  Mesh degenerate;
  degenerate.positions = {{0, 0, 0}, {1, 1, 1}};
  degenerate.indices = {0, 0, 0, 0, 1, 1};
  VoxelizeStats st;
  const VoxelSet set = voxelize(degenerate.input(), o, &st);
  EXPECT_EQ(st.degenerate_triangles, 2u);
  EXPECT_GE(set.size(), 8u);  // the diagonal crosses the 8 diagonal voxels (and touches more)
  for (const VoxelAttributes& a : set.attrs) EXPECT_TRUE(is_finite(a.normal) && std::isfinite(a.contour_lo));
}

// --- CLI -----------------------------------------------------------------------------------

using test::RunResult;
using test::run_cli;
using test::slurp;

TEST(VoxelizeCli, XyzListsVoxelsInLexicographicOrder) {
  if (std::string(SPECULA_CLI_PATH).empty()) GTEST_SKIP() << "specula CLI not built";
  const fs::path dir = test::temp_dir("voxelize-cli");
  const fs::path obj = dir / "quad.obj";
  // The quad z = 0 over [-1,1]^2: the grid's cube is [-1,1]^2 x [0,2]; at depth 2 the quad
  // lies on the bottom face of layer z = 0 and touches all 16 voxels of it.
  std::ofstream(obj) << "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n";
  const RunResult r = run_cli("voxelize '" + obj.string() + "' --depth 2 --format xyz", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::string expected;
  for (int x = 0; x < 4; ++x)
    for (int y = 0; y < 4; ++y) expected += std::to_string(x) + " " + std::to_string(y) + " 0\n";
  EXPECT_EQ(r.out, expected);
  EXPECT_NE(r.err.find("voxels    16"), std::string::npos) << r.err;

  // -o FILE.xyz writes the same lines; the summary goes to stdout.
  const RunResult w = run_cli("voxelize '" + obj.string() + "' --depth 2 -o '" + (dir / "v.xyz").string() + "'", dir);
  ASSERT_EQ(w.exit_code, 0) << w.err;
  EXPECT_EQ(slurp(dir / "v.xyz"), expected);
  EXPECT_NE(w.out.find("bytes"), std::string::npos) << w.out;
  EXPECT_NE(w.out.find("ms"), std::string::npos) << w.out;

  // Errors: unknown test, bad depth, unsupported output, refused memory.
  EXPECT_EQ(run_cli("voxelize '" + obj.string() + "' --depth 2 --tests aabb,foo", dir).exit_code, 1);
  EXPECT_NE(run_cli("voxelize '" + obj.string() + "' --depth 22", dir).exit_code, 0);
  EXPECT_EQ(run_cli("voxelize '" + obj.string() + "' --depth 2 -o '" + (dir / "v.svo2").string() + "'", dir).exit_code, 1);
  const RunResult big = run_cli("voxelize '" + obj.string() + "' --depth 21 --memory-limit 1M", dir);
  EXPECT_EQ(big.exit_code, 1);
  EXPECT_NE(big.err.find("bytes"), std::string::npos) << big.err;
  const RunResult help = run_cli("voxelize --help", dir);
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.out.find("--sat-at"), std::string::npos);
  fs::remove_all(dir);
}

}  // namespace
