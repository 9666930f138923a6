/// \file voxelize.cpp
/// The exact, multi-threaded, sparse surface voxelizer (see include/specula/voxelize.h and
/// docs/voxels.md).
///
/// Pipeline:
///  1. validate: indices in range, vertices finite, depth and strategy valid; grid bounds.
///  2. estimate: an upper bound of the memory needed (per triangle, the smaller of its
///     bounding-box voxel count and the volume of the triangle grown by a voxel diagonal,
///     which every voxel it touches lies in); refuse before allocating when over the limit.
///  3. prepare (parallel): snap vertices to the integer lattice, precompute the exact tests.
///  4. bin (parallel): descend the implicit octree from the root to the brick level
///     (32^3 leaf voxels per brick) with the strategy's tests, emitting (brick, triangle);
///     sort by brick, then triangle.
///  5. voxel (parallel over bricks): each brick runs its triangles in index order through the
///     leaf tests (octree descent from the brick node, or the leaf voxels of the triangle's
///     bounding box), clips each (voxel, triangle) pair to the voxel for its area and polygon,
///     then averages attributes and computes contours per voxel. Output per brick is sorted by
///     Morton code, so bricks in code order concatenate into a sorted set.
///  6. gather: concatenate the bricks' outputs.
/// Every sum of floating-point numbers runs in a fixed order (triangle index order inside a
/// brick), so the result is bit-identical for any thread count.
#include "specula/voxelize.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include "specula/error.h"
#include "specula/timer.h"
#include "voxel/tri_box.h"

namespace specula {

using voxel::kLatticeBits;
using voxel::kLatticeSide;
using voxel::LatticeBox;
using voxel::TriBox;

std::string VoxelStrategy::describe() const {
  std::string s = "aabb";
  if (plane) s += "+plane";
  if (sat) s += sat_at == SatLevel::All ? "+sat (every level)" : "+sat (leaf level)";
  if (vertex_shortcut) s += ", vertex shortcut";
  s += traversal == VoxelTraversal::Octree ? ", octree descent" : ", brick + bbox range";
  return s;
}

std::vector<TriangleAttributes> triangle_attributes(const Scene& scene) {
  const size_t n = scene.triangle_count();
  std::vector<TriangleAttributes> out(n);
  for (size_t i = 0; i < n; ++i) {
    const uint32_t id = i < scene.material_ids.size() ? scene.material_ids[i] : 0;
    TriangleAttributes& a = out[i];
    a.material = id;
    if (id < scene.materials.size()) {
      const Material& m = scene.materials[id];
      a.colour = m.diffuse;
      a.reflectivity = m.reflectivity;
      a.transparency = m.transparency;
      a.ior = m.ior;
    }
  }
  return out;
}

uint64_t default_voxelize_memory_limit() {
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page <= 0) return uint64_t{4} << 30;
  return static_cast<uint64_t>(pages) * static_cast<uint64_t>(page) / 2;
}

namespace {

/// Leaf voxels per brick side at most: 2^kBrickBits (32), so a brick holds up to 32^3 voxels.
constexpr int kBrickBits = 5;
constexpr uint32_t kNoSlot = 0xFFFFFFFFu;

std::string bytes_text(double b) {
  char buf[64];
  const char* unit[] = {"B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  int u = 0;
  double v = b;
  while (v >= 1024.0 && u < 6) {
    v /= 1024.0;
    ++u;
  }
  std::snprintf(buf, sizeof buf, "%.4g %s", v, unit[u]);
  return buf;
}

/// What the input validation found.
struct Checked {
  size_t triangles = 0;
  Aabb bounds;
  VoxelGrid grid;
  int brick_bits = 0;   ///< leaf voxels per brick side = 2^brick_bits
  int brick_level = 0;  ///< depth of the brick nodes
  int threads = 1;
};

/// Lowest index of a bad triangle (index out of range or non-finite vertex), or SIZE_MAX.
struct BadScan {
  size_t first_bad = std::numeric_limits<size_t>::max();
  Aabb bounds;
};

Checked check(const VoxelizeInput& in, const VoxelizeOptions& o) {
  if (o.depth < 1 || o.depth > kMaxVoxelDepth)
    throw Error("voxelize: depth " + std::to_string(o.depth) + " is outside 1.." + std::to_string(kMaxVoxelDepth));
  if (o.strategy.sat_at == SatLevel::All && !o.strategy.sat)
    throw Error("voxelize: 'SAT at every level' needs the SAT test enabled");
  if (o.strategy.sat_at == SatLevel::All && o.strategy.traversal == VoxelTraversal::Range)
    throw Error("voxelize: 'SAT at every level' needs the octree traversal (the range traversal has no inner levels)");
  if (in.indices.size() % 3 != 0)
    throw Error("voxelize: index count " + std::to_string(in.indices.size()) + " is not a multiple of 3");
  const size_t n = in.indices.size() / 3;
  if (n == 0) throw Error("voxelize: no triangles to voxelize");
  if (n > 0xFFFFFFF0u) throw Error("voxelize: more than 2^32 triangles");
  if (!in.attributes.empty() && in.attributes.size() != n)
    throw Error("voxelize: " + std::to_string(in.attributes.size()) + " triangle attributes for " +
                std::to_string(n) + " triangles");
  if (o.threads < 0) throw Error("voxelize: negative thread count");

  const size_t np = in.positions.size();
  auto scan = [&](size_t b, size_t e, BadScan acc) {
    for (size_t t = b; t < e && t < acc.first_bad; ++t) {
      for (int k = 0; k < 3; ++k) {
        const uint32_t i = in.indices[3 * t + k];
        if (i >= np || !is_finite(in.positions[i])) {
          acc.first_bad = std::min(acc.first_bad, t);
          break;
        }
        acc.bounds.grow(in.positions[i]);
      }
    }
    return acc;
  };
  const BadScan scanned = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 4096), BadScan{},
      [&](const tbb::blocked_range<size_t>& r, BadScan acc) { return scan(r.begin(), r.end(), acc); },
      [](BadScan a, const BadScan& b) {
        a.first_bad = std::min(a.first_bad, b.first_bad);
        a.bounds.grow(b.bounds);
        return a;
      });
  if (scanned.first_bad != std::numeric_limits<size_t>::max()) {
    const size_t t = scanned.first_bad;
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = in.indices[3 * t + k];
      if (i >= np)
        throw Error("voxelize: triangle " + std::to_string(t) + ": vertex index " + std::to_string(i) +
                    " out of range (" + std::to_string(np) + " positions)");
      if (!is_finite(in.positions[i]))
        throw Error("voxelize: triangle " + std::to_string(t) + ": vertex " + std::to_string(i) +
                    " is not finite (NaN or infinity)");
    }
  }

  Checked c;
  c.triangles = n;
  c.bounds = scanned.bounds;
  if (o.bounds) {
    const Aabb& b = *o.bounds;
    if (b.empty() || !is_finite(b.min) || !is_finite(b.max))
      throw Error("voxelize: the given grid bounds are empty or not finite");
    const Aabb& v = scanned.bounds;
    if (v.min.x < b.min.x || v.min.y < b.min.y || v.min.z < b.min.z || v.max.x > b.max.x || v.max.y > b.max.y ||
        v.max.z > b.max.z)
      throw Error("voxelize: the given grid bounds do not contain every vertex");
    c.bounds = b;
  }
  c.grid = VoxelGrid::around(c.bounds, o.depth);
  if (!std::isfinite(c.grid.side) || !(c.grid.side > 0.0f))
    throw Error("voxelize: the scene's extent is not a finite positive number");
  // 32^3 bricks from depth 8 on; smaller ones at low depths so there are bricks to share out.
  c.brick_bits = std::clamp(o.depth - 3, 1, kBrickBits);
  c.brick_level = o.depth - c.brick_bits;
  c.threads = o.threads > 0 ? o.threads : tbb::info::default_concurrency();
  return c;
}

/// Vertex -> lattice coordinates (see tri_box.h): [0, 2^29] over the root cube.
struct Snapper {
  double origin[3];
  double scale;
  explicit Snapper(const VoxelGrid& g)
      : origin{g.origin.x, g.origin.y, g.origin.z}, scale(static_cast<double>(kLatticeSide) / g.side) {}
  void operator()(const Vec3& p, int64_t out[3]) const {
    for (int k = 0; k < 3; ++k) {
      const double v = std::nearbyint((static_cast<double>(p[k]) - origin[k]) * scale);
      // Vertices on the far side can land a rounding step outside (the side is a float).
      out[k] = static_cast<int64_t>(std::clamp(v, 0.0, static_cast<double>(kLatticeSide)));
    }
  }
};

/// Sizes that the memory estimate multiplies.
struct PerVoxelBytes {
  static constexpr double code = sizeof(uint64_t);
  static constexpr double attrs = sizeof(VoxelAttributes);
};

/// Upper bound of the number of voxels of side 1 that a triangle with vertices \p a, \p b, \p c
/// (in voxel units) can touch: the smaller of its bounding-box voxel count (closed boxes: a
/// range [lo, hi] touches floor(hi) - ceil(lo) + 2 voxels at most) and the volume of the
/// triangle grown by a voxel diagonal r = sqrt(3) (Steiner: 2 r A + pi r^2 P / 2 + 4/3 pi r^3),
/// which contains every voxel the triangle touches.
double touched_bound(const double a[3], const double b[3], const double c[3], double res) {
  double box = 1.0;
  for (int k = 0; k < 3; ++k) {
    const double lo = std::min({a[k], b[k], c[k]}), hi = std::max({a[k], b[k], c[k]});
    const double first = std::max(0.0, std::ceil(lo) - 1.0), last = std::min(res - 1.0, std::floor(hi));
    box *= std::max(1.0, last - first + 1.0);
  }
  const double e0[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  const double e1[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  const double e2[3] = {c[0] - b[0], c[1] - b[1], c[2] - b[2]};
  const double cr[3] = {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2], e0[0] * e1[1] - e0[1] * e1[0]};
  const double area = 0.5 * std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
  auto len = [](const double* e) { return std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]); };
  const double perimeter = len(e0) + len(e1) + len(e2);
  const double r = std::sqrt(3.0);
  const double steiner = 2.0 * r * area + 0.5 * 3.14159265358979 * r * r * perimeter + 4.0 / 3.0 * 3.14159265358979 * r * r * r;
  return std::ceil(std::min(box, steiner));
}

struct Estimate {
  double pair_bound = 0;        ///< (voxel, triangle) incidences
  double brick_pair_bound = 0;  ///< (brick, triangle) incidences
  double voxel_bound = 0;
  double bytes = 0;
};

// Per-brick scratch sizes used by the estimate and by the code.
struct Slot {
  double w = 0, n[3] = {0, 0, 0}, col[3] = {0, 0, 0}, refl = 0, transp = 0, ior = 0;
  double un[3] = {0, 0, 0}, ucol[3] = {0, 0, 0}, urefl = 0, utransp = 0, uior = 0;
  uint32_t count = 0;
  float best_area = -1.0f;
  uint32_t best_tri = 0;
  double cmin = 0, cmax = 0;
  uint32_t verts = 0;
  float normal[3] = {0, 0, 1};
};
struct PairRec {
  uint32_t slot;
  uint32_t tri;
  float area;       ///< area of the triangle's part inside the voxel, in voxel-side^2 units
  uint32_t vfirst;  ///< first vertex of its clipped polygon in Scratch::verts
  uint32_t vcount;
};
struct BinEntry {
  uint64_t brick;
  uint32_t tri;
  bool operator<(const BinEntry& o) const { return brick != o.brick ? brick < o.brick : tri < o.tri; }
};

Estimate estimate(const VoxelizeInput& in, const Checked& c, const VoxelizeOptions& o) {
  const Snapper snap(c.grid);
  const double leaf_res = std::ldexp(1.0, o.depth);
  const double to_leaf = std::ldexp(1.0, o.depth - kLatticeBits);
  const double brick_res = std::ldexp(1.0, c.brick_level);
  const double to_brick = std::ldexp(1.0, c.brick_level - kLatticeBits);
  struct Sums {
    double pairs = 0, brick_pairs = 0;
  };
  // Per-triangle bounds are integers (ceil), so the sums are exact below 2^53 and the estimate
  // does not depend on how TBB splits the range.
  const Sums s = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, c.triangles, 4096), Sums{},
      [&](const tbb::blocked_range<size_t>& r, Sums acc) {
        for (size_t t = r.begin(); t < r.end(); ++t) {
          double v[3][3], vb[3][3];
          for (int k = 0; k < 3; ++k) {
            int64_t l[3];
            snap(in.positions[in.indices[3 * t + k]], l);
            for (int j = 0; j < 3; ++j) {
              v[k][j] = static_cast<double>(l[j]) * to_leaf;
              vb[k][j] = static_cast<double>(l[j]) * to_brick;
            }
          }
          acc.pairs += touched_bound(v[0], v[1], v[2], leaf_res);
          acc.brick_pairs += touched_bound(vb[0], vb[1], vb[2], brick_res);
        }
        return acc;
      },
      [](Sums a, const Sums& b) {
        a.pairs += b.pairs;
        a.brick_pairs += b.brick_pairs;
        return a;
      });
  Estimate e;
  e.pair_bound = s.pairs;
  e.brick_pair_bound = s.brick_pairs;
  e.voxel_bound = std::min(s.pairs, std::ldexp(1.0, 3 * o.depth));
  const double n = static_cast<double>(c.triangles);
  const double per_voxel = PerVoxelBytes::code + (o.attributes ? PerVoxelBytes::attrs : 0.0);
  const double brick_voxels = std::ldexp(1.0, 3 * c.brick_bits);
  e.bytes = n * (sizeof(TriBox) + sizeof(Vec3) + 4 + 16)             // prepared triangles, order
            + 2.0 * e.brick_pair_bound * sizeof(BinEntry)           // bins (+ sort buffer)
            + 2.0 * e.voxel_bound * per_voxel                       // brick outputs + the set
            + c.threads * brick_voxels * (sizeof(uint32_t) + (o.attributes ? sizeof(Slot) : 4.0));
  if (o.attributes)  // pair records and clipped polygons of the bricks in flight
    e.bytes += std::min(e.pair_bound, c.threads * brick_voxels * 8.0) * (sizeof(PairRec) + 9 * 3 * sizeof(float));
  return e;
}

/// Spreads 5 bits so bit i lands on bit 3i (Morton code inside a brick).
constexpr std::array<uint32_t, 32> make_spread5() {
  std::array<uint32_t, 32> t{};
  for (uint32_t v = 0; v < 32; ++v) {
    uint32_t r = 0;
    for (int b = 0; b < 5; ++b) r |= ((v >> b) & 1u) << (3 * b);
    t[v] = r;
  }
  return t;
}
constexpr std::array<uint32_t, 32> kSpread5 = make_spread5();

struct Counters {
  uint64_t aabb = 0, plane = 0, sat = 0, vertex = 0, pairs = 0;
};

/// Which tests run at inner levels and at leaves.
struct Tests {
  bool plane_inner = false, sat_inner = false;
  bool plane_leaf = false, sat_leaf = false, shortcut = false;
  int depth = 0;

  /// Box tests after the AABB stage; \p leaf selects the leaf set.
  bool pass(const TriBox& t, const LatticeBox& b, bool leaf, Counters& c) const {
    if (leaf && shortcut && voxel::vertex_inside(t, b)) {
      ++c.vertex;
      return true;
    }
    const bool plane = leaf ? plane_leaf : plane_inner;
    const bool sat = leaf ? sat_leaf : sat_inner;
    if (plane || sat) {  // the SAT includes the triangle-normal axis
      ++c.plane;
      if (!voxel::plane_overlap(t, b)) return false;
    }
    if (sat) {
      ++c.sat;
      if (!voxel::edge_overlap(t, b)) return false;
    }
    return true;
  }

  /// Descends from node (x, y, z) at \p level (which the triangle overlaps) to \p target,
  /// calling emit(x, y, z) for every node at \p target that passes. The AABB stage uses the
  /// children's shared corner (seed 000's trick): two comparisons per axis decide the 8 children.
  template <class Emit>
  void descend(const TriBox& t, int level, uint32_t x, uint32_t y, uint32_t z, int target, Counters& c,
               Emit& emit) const {
    const int child_level = level + 1;
    const int shift = kLatticeBits - child_level;
    const int64_t size = int64_t{1} << shift;
    const uint32_t p[3] = {x, y, z};
    uint32_t mask[3];
    for (int k = 0; k < 3; ++k) {
      const int64_t centre = (2 * static_cast<int64_t>(p[k]) + 1) << shift;
      mask[k] = (t.lo[k] <= centre ? 1u : 0u) | (t.hi[k] >= centre ? 2u : 0u);
    }
    const bool leaf = child_level == depth;
    for (uint32_t cz = 0; cz < 2; ++cz) {
      if (!(mask[2] >> cz & 1u)) continue;
      for (uint32_t cy = 0; cy < 2; ++cy) {
        if (!(mask[1] >> cy & 1u)) continue;
        for (uint32_t cx = 0; cx < 2; ++cx) {
          if (!(mask[0] >> cx & 1u)) continue;
          ++c.aabb;
          const uint32_t X = 2 * x + cx, Y = 2 * y + cy, Z = 2 * z + cz;
          const LatticeBox box{{static_cast<int64_t>(X) << shift, static_cast<int64_t>(Y) << shift,
                                static_cast<int64_t>(Z) << shift},
                               size};
          if (!pass(t, box, leaf, c)) continue;
          if (child_level == target)
            emit(X, Y, Z);
          else
            descend(t, child_level, X, Y, Z, target, c, emit);
        }
      }
    }
  }
};

Tests make_tests(const VoxelStrategy& s, int depth) {
  Tests t;
  t.depth = depth;
  if (s.traversal == VoxelTraversal::Octree) {
    t.plane_inner = s.plane;
    t.sat_inner = s.sat && s.sat_at == SatLevel::All;
  } else {
    // Range: inner levels (down to the bricks) only prune; any test the leaf will apply is
    // monotone, so pruning with it changes nothing but the work.
    t.plane_inner = s.plane || s.sat;
    t.sat_inner = s.sat;
  }
  t.plane_leaf = s.plane;
  t.sat_leaf = s.sat;
  t.shortcut = s.vertex_shortcut;
  return t;
}

/// A convex polygon (possibly degenerate) of at most 12 vertices; a triangle cut by the 6
/// planes of a box has at most 9.
struct Poly {
  int n = 0;
  double p[12][3];
};

void copy_poly(const Poly& from, Poly& to) {
  to.n = from.n;
  for (int i = 0; i < from.n; ++i)
    for (int k = 0; k < 3; ++k) to.p[i][k] = from.p[i][k];
}

/// Cuts \p in by the plane x[axis] = c into its closed halves: \p below (x <= c) and
/// \p above (x >= c). Vertices on the plane go to both (a touching polygon stays non-empty).
void split(const Poly& in, int axis, double c, Poly& below, Poly& above) {
  below.n = 0;
  above.n = 0;
  auto put = [](Poly& q, const double* v) {
    if (q.n < 12) {
      for (int k = 0; k < 3; ++k) q.p[q.n][k] = v[k];
      ++q.n;
    }
  };
  for (int i = 0; i < in.n; ++i) {
    const double* a = in.p[i];
    const double* b = in.p[i + 1 == in.n ? 0 : i + 1];
    const double da = a[axis] - c, db = b[axis] - c;
    if (da <= 0.0) put(below, a);
    if (da >= 0.0) put(above, a);
    if ((da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0)) {
      const double t = da / (da - db);
      double q[3];
      for (int k = 0; k < 3; ++k) q[k] = a[k] + (b[k] - a[k]) * t;
      q[axis] = c;
      put(below, q);
      put(above, q);
    }
  }
}

/// Area of a planar polygon.
double polygon_area(const std::array<double, 3>* p, int n) {
  double s[3] = {0, 0, 0};
  for (int i = 1; i + 1 < n; ++i) {
    const double a[3] = {p[i][0] - p[0][0], p[i][1] - p[0][1], p[i][2] - p[0][2]};
    const double b[3] = {p[i + 1][0] - p[0][0], p[i + 1][1] - p[0][1], p[i + 1][2] - p[0][2]};
    s[0] += a[1] * b[2] - a[2] * b[1];
    s[1] += a[2] * b[0] - a[0] * b[2];
    s[2] += a[0] * b[1] - a[1] * b[0];
  }
  return 0.5 * std::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
}

/// Per-thread scratch of the brick stage.
struct Scratch {
  std::vector<uint32_t> slot_of;  ///< local Morton code -> slot (kNoSlot when untouched)
  std::vector<uint32_t> touched;  ///< local codes touched in this brick, first-touch order
  std::vector<Slot> slots;
  std::vector<PairRec> pairs;
  std::vector<std::array<float, 3>> verts;
  /// The current triangle's parts per leaf voxel of its bounding-box range in the brick:
  /// cell -> (first vertex in pverts, vertex count); count 0 = no part.
  std::vector<std::array<uint32_t, 2>> cells;
  std::vector<std::array<double, 3>> pverts;
  Counters counters;
};

struct BrickOut {
  std::vector<uint64_t> codes;
  std::vector<VoxelAttributes> attrs;
};

struct Context {
  const VoxelizeInput& in;
  const VoxelizeOptions& opt;
  const Checked& chk;
  const Tests& tests;
  const std::vector<TriBox>& tris;
  const std::vector<Vec3>& normals;
  const std::vector<uint32_t>& original;  ///< prepared (Morton-ordered) index -> input index
  int leaf_shift = 0;  ///< lattice units per leaf voxel = 2^leaf_shift
};

const TriangleAttributes& attrs_of(const Context& cx, uint32_t t) {
  static const TriangleAttributes kDefault{};
  return cx.in.attributes.empty() ? kDefault : cx.in.attributes[cx.original[t]];
}

void process_brick(const Context& cx, uint64_t brick, const BinEntry* first, const BinEntry* last, Scratch& s,
                   BrickOut& out) {
  const int bb = cx.chk.brick_bits;
  const uint32_t bmask = (1u << bb) - 1u;
  uint32_t bx, by, bz;
  morton_decode(brick, bx, by, bz);
  const uint32_t base[3] = {bx << bb, by << bb, bz << bb};
  const int F = cx.leaf_shift;
  const int64_t S = int64_t{1} << F;
  const double inv_s = std::ldexp(1.0, -F);
  const bool attrs = cx.opt.attributes;
  const uint32_t res_max = (1u << cx.opt.depth) - 1u;

  s.touched.clear();
  s.slots.clear();
  s.pairs.clear();
  s.verts.clear();

  uint32_t cur_tri = 0;
  const TriBox* cur = nullptr;
  uint32_t r0[3] = {0, 0, 0}, r1[3] = {0, 0, 0};  // the current triangle's leaf range in the brick
  uint32_t rn[3] = {0, 0, 0};
  auto accept = [&](uint32_t X, uint32_t Y, uint32_t Z) {
    ++s.counters.pairs;
    const uint32_t lcode = kSpread5[X & bmask] | kSpread5[Y & bmask] << 1 | kSpread5[Z & bmask] << 2;
    uint32_t slot = s.slot_of[lcode];
    if (slot == kNoSlot) {
      slot = static_cast<uint32_t>(s.touched.size());
      s.slot_of[lcode] = slot;
      s.touched.push_back(lcode);
      if (attrs) s.slots.emplace_back();
    }
    if (!attrs) return;
    const auto& cell = s.cells[((Z - r0[2]) * rn[1] + (Y - r0[1])) * rn[0] + (X - r0[0])];
    const std::array<double, 3>* piece = s.pverts.data() + cell[0];
    const int n = static_cast<int>(cell[1]);
    PairRec p;
    p.slot = slot;
    p.tri = cur_tri;
    p.area = n >= 3 ? static_cast<float>(polygon_area(piece, n)) : 0.0f;
    p.vfirst = static_cast<uint32_t>(s.verts.size());
    p.vcount = static_cast<uint32_t>(n);
    const double o[3] = {static_cast<double>(X - base[0]), static_cast<double>(Y - base[1]),
                         static_cast<double>(Z - base[2])};
    for (int i = 0; i < n; ++i)
      s.verts.push_back({static_cast<float>(piece[i][0] - o[0]), static_cast<float>(piece[i][1] - o[1]),
                         static_cast<float>(piece[i][2] - o[2])});
    s.pairs.push_back(p);
  };

  // Cuts the triangle into its parts per leaf voxel of the range (slabs along x, then y, then
  // z; each cut is one plane), in brick-local leaf units. Cost ~ the number of parts.
  auto cut_parts = [&](const TriBox& t) {
    s.cells.assign(static_cast<size_t>(rn[0]) * rn[1] * rn[2], {0u, 0u});
    s.pverts.clear();
    Poly tri;
    tri.n = 3;
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k)
        tri.p[i][k] = static_cast<double>(t.v[i][k] - (static_cast<int64_t>(base[k]) << F)) * inv_s;
    uint32_t idx[3] = {0, 0, 0};
    auto slabs = [&](auto& self, const Poly& poly, int axis) -> void {
      const double lo = static_cast<double>(r0[axis] - base[axis]);
      const uint32_t count = rn[axis];
      Poly rest, piece, tmp;
      double mn = poly.p[0][axis], mx = mn;
      for (int i = 1; i < poly.n; ++i) {
        mn = std::min(mn, poly.p[i][axis]);
        mx = std::max(mx, poly.p[i][axis]);
      }
      if (mn < lo)
        split(poly, axis, lo, tmp, rest);
      else
        copy_poly(poly, rest);
      for (uint32_t c = 0; c < count && rest.n > 0; ++c) {
        const double top = lo + static_cast<double>(c) + 1.0;
        if (mx >= top) {
          split(rest, axis, top, piece, tmp);
          copy_poly(tmp, rest);
        } else {
          copy_poly(rest, piece);
          rest.n = 0;
        }
        if (piece.n == 0) continue;
        idx[axis] = c;
        if (axis < 2) {
          self(self, piece, axis + 1);
        } else {
          auto& cell = s.cells[(static_cast<size_t>(idx[2]) * rn[1] + idx[1]) * rn[0] + idx[0]];
          cell = {static_cast<uint32_t>(s.pverts.size()), static_cast<uint32_t>(piece.n)};
          for (int i = 0; i < piece.n; ++i) s.pverts.push_back({piece.p[i][0], piece.p[i][1], piece.p[i][2]});
        }
      }
    };
    slabs(slabs, tri, 0);
  };

  const bool octree = cx.opt.strategy.traversal == VoxelTraversal::Octree;
  const bool plane_cut = cx.tests.plane_leaf || cx.tests.sat_leaf;
  for (const BinEntry* e = first; e != last; ++e) {
    cur_tri = e->tri;
    cur = &cx.tris[e->tri];
    const TriBox& t = *cur;
    // The leaf voxels of the triangle's bounding box inside this brick. Voxel x (lattice
    // [x S, (x+1) S]) meets [lo, hi] iff ceil(lo / S) - 1 <= x <= floor(hi / S).
    bool empty = false;
    for (int k = 0; k < 3; ++k) {
      const int64_t a = ((t.lo[k] + S - 1) >> F) - 1;
      const int64_t b = t.hi[k] >> F;
      const int64_t lo = std::max<int64_t>({a, 0, base[k]});
      const int64_t hi = std::min<int64_t>({b, res_max, base[k] + bmask});
      if (lo > hi) empty = true;
      r0[k] = static_cast<uint32_t>(lo);
      r1[k] = static_cast<uint32_t>(hi);
      rn[k] = static_cast<uint32_t>(hi - lo + 1);
    }
    if (empty) continue;
    if (attrs) cut_parts(t);
    if (octree) {
      cx.tests.descend(t, cx.chk.brick_level, bx, by, bz, cx.opt.depth, s.counters, accept);
      continue;
    }
    auto try_voxel = [&](uint32_t x, uint32_t y, uint32_t z) {
      ++s.counters.aabb;
      const LatticeBox box{{static_cast<int64_t>(x) << F, static_cast<int64_t>(y) << F, static_cast<int64_t>(z) << F}, S};
      if (cx.tests.pass(t, box, true, s.counters)) accept(x, y, z);
    };
    if (!plane_cut || (t.n[0] == 0 && t.n[1] == 0 && t.n[2] == 0)) {
      for (uint32_t z = r0[2]; z <= r1[2]; ++z)
        for (uint32_t y = r0[1]; y <= r1[1]; ++y)
          for (uint32_t x = r0[0]; x <= r1[0]; ++x) try_voxel(x, y, z);
      continue;
    }
    // Columns along the normal's dominant axis w: only the voxels near the plane's w-range
    // over the column are tried (the exact plane test in pass() still decides).
    const int w = (std::abs(t.n[0]) >= std::abs(t.n[1]) && std::abs(t.n[0]) >= std::abs(t.n[2]))
                      ? 0
                      : (std::abs(t.n[1]) >= std::abs(t.n[2]) ? 1 : 2);
    const int u = (w + 1) % 3, v = (w + 2) % 3;
    const int64_t sg = t.n[w] > 0 ? 1 : -1;
    const int64_t nu = sg * t.n[u], nv = sg * t.n[v];
    const __int128 dd = sg * t.d;
    const int64_t pos = (nu > 0 ? nu : 0) + (nv > 0 ? nv : 0), neg = (nu < 0 ? nu : 0) + (nv < 0 ? nv : 0);
    const double denom = static_cast<double>(sg * t.n[w]) * static_cast<double>(S);
    uint32_t q[3];
    for (uint32_t cv = r0[v]; cv <= r1[v]; ++cv)
      for (uint32_t cu = r0[u]; cu <= r1[u]; ++cu) {
        const __int128 a = static_cast<__int128>(nu) * (static_cast<int64_t>(cu) << F) +
                           static_cast<__int128>(nv) * (static_cast<int64_t>(cv) << F);
        const __int128 gmin = dd - (a + static_cast<__int128>(pos) * S);
        const __int128 gmax = dd - (a + static_cast<__int128>(neg) * S);
        const double kmin = std::ceil(static_cast<double>(gmin) / denom - 1e-6) - 1.0;
        const double kmax = std::floor(static_cast<double>(gmax) / denom + 1e-6);
        const double k0 = std::max(kmin, static_cast<double>(r0[w]));
        const double k1 = std::min(kmax, static_cast<double>(r1[w]));
        if (k0 > k1) continue;
        q[u] = cu;
        q[v] = cv;
        for (uint32_t k = static_cast<uint32_t>(k0); k <= static_cast<uint32_t>(k1); ++k) {
          q[w] = k;
          try_voxel(q[0], q[1], q[2]);
        }
      }
  }

  // Output in Morton order.
  std::vector<uint32_t>& order = s.touched;
  const size_t nv = order.size();
  std::vector<uint32_t> sorted(order);
  std::sort(sorted.begin(), sorted.end());
  const uint64_t high = brick << (3 * bb);
  out.codes.resize(nv);
  for (size_t i = 0; i < nv; ++i) out.codes[i] = high | sorted[i];

  if (attrs) {
    // Weighted (by clipped area) and unweighted sums, in pair order = triangle order.
    for (const PairRec& p : s.pairs) {
      Slot& sl = s.slots[p.slot];
      const Vec3& nrm = cx.normals[p.tri];
      const TriangleAttributes& a = attrs_of(cx, p.tri);
      const double w = p.area;
      sl.w += w;
      sl.n[0] += w * nrm.x;
      sl.n[1] += w * nrm.y;
      sl.n[2] += w * nrm.z;
      sl.col[0] += w * a.colour.x;
      sl.col[1] += w * a.colour.y;
      sl.col[2] += w * a.colour.z;
      sl.refl += w * a.reflectivity;
      sl.transp += w * a.transparency;
      sl.ior += w * a.ior;
      sl.un[0] += nrm.x;
      sl.un[1] += nrm.y;
      sl.un[2] += nrm.z;
      sl.ucol[0] += a.colour.x;
      sl.ucol[1] += a.colour.y;
      sl.ucol[2] += a.colour.z;
      sl.urefl += a.reflectivity;
      sl.utransp += a.transparency;
      sl.uior += a.ior;
      ++sl.count;
      if (p.area > sl.best_area) {
        sl.best_area = p.area;
        sl.best_tri = p.tri;
      }
    }
    for (Slot& sl : s.slots) {
      const bool weighted = sl.w > 0.0;
      const double* nn = weighted ? sl.n : sl.un;
      const double len = std::sqrt(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
      const double scale = weighted ? sl.w : static_cast<double>(sl.count);
      double nv3[3] = {0, 0, 1};
      if (len > 1e-9 * scale) {
        for (int k = 0; k < 3; ++k) nv3[k] = nn[k] / len;
      } else {  // normals cancel (e.g. two sides of a thin wall): the largest triangle's
        const Vec3& b = cx.normals[sl.best_tri];
        if (b != Vec3{}) nv3[0] = b.x, nv3[1] = b.y, nv3[2] = b.z;
      }
      for (int k = 0; k < 3; ++k) sl.normal[k] = static_cast<float>(nv3[k]);
      sl.cmin = std::numeric_limits<double>::infinity();
      sl.cmax = -std::numeric_limits<double>::infinity();
    }
    for (const PairRec& p : s.pairs) {
      Slot& sl = s.slots[p.slot];
      const double n0 = sl.normal[0], n1 = sl.normal[1], n2 = sl.normal[2];
      for (uint32_t i = 0; i < p.vcount; ++i) {
        const auto& v = s.verts[p.vfirst + i];
        const double d = n0 * (v[0] - 0.5) + n1 * (v[1] - 0.5) + n2 * (v[2] - 0.5);
        sl.cmin = std::min(sl.cmin, d);
        sl.cmax = std::max(sl.cmax, d);
      }
      sl.verts += p.vcount;
    }
    const double side = static_cast<double>(cx.chk.grid.voxel_size());
    out.attrs.resize(nv);
    for (size_t i = 0; i < nv; ++i) {
      const Slot& sl = s.slots[s.slot_of[sorted[i]]];
      VoxelAttributes& a = out.attrs[i];
      const bool weighted = sl.w > 0.0;
      const double inv = 1.0 / (weighted ? sl.w : static_cast<double>(sl.count));
      const double* col = weighted ? sl.col : sl.ucol;
      a.normal = {sl.normal[0], sl.normal[1], sl.normal[2]};
      a.colour = {static_cast<float>(col[0] * inv), static_cast<float>(col[1] * inv), static_cast<float>(col[2] * inv)};
      a.reflectivity = static_cast<float>((weighted ? sl.refl : sl.urefl) * inv);
      a.transparency = static_cast<float>((weighted ? sl.transp : sl.utransp) * inv);
      a.ior = static_cast<float>((weighted ? sl.ior : sl.uior) * inv);
      a.material = attrs_of(cx, sl.best_tri).material;
      // Contours in world units; widened by 1e-5 voxel for the rounding of clipping.
      const double half = 0.5 * (std::fabs(static_cast<double>(sl.normal[0])) + std::fabs(static_cast<double>(sl.normal[1])) +
                                 std::fabs(static_cast<double>(sl.normal[2])));
      double lo = -half, hi = half;  // no polygon survived (touching only): the whole voxel
      if (sl.verts > 0 && sl.cmin <= sl.cmax) {
        lo = std::max(-half, sl.cmin - 1e-5);
        hi = std::min(half, sl.cmax + 1e-5);
      }
      a.contour_lo = static_cast<float>(lo * side);
      a.contour_hi = static_cast<float>(hi * side);
    }
  }
  for (uint32_t code : order) s.slot_of[code] = kNoSlot;
}

}  // namespace

uint64_t voxelize_memory_estimate(const VoxelizeInput& input, const VoxelizeOptions& options) {
  const Checked c = check(input, options);
  const double b = estimate(input, c, options).bytes;
  return b >= 1.8e19 ? std::numeric_limits<uint64_t>::max() : static_cast<uint64_t>(b);
}

VoxelSet voxelize(const VoxelizeInput& input, const VoxelizeOptions& options, VoxelizeStats* stats_out) {
  Timer total;
  VoxelizeStats st;
  const Checked chk = check(input, options);
  st.threads = chk.threads;
  st.triangles = chk.triangles;

  tbb::task_arena arena(chk.threads);
  VoxelSet result;
  arena.execute([&] {
    // 2. estimate and limit.
    const Estimate est = estimate(input, chk, options);
    st.estimate_bytes = est.bytes >= 1.8e19 ? std::numeric_limits<uint64_t>::max() : static_cast<uint64_t>(est.bytes);
    st.memory_limit = options.memory_limit == 0 ? default_voxelize_memory_limit() : options.memory_limit;
    if (est.bytes > static_cast<double>(st.memory_limit)) {
      char buf[512];
      std::snprintf(buf, sizeof buf,
                    "voxelize: depth %d would need up to %.4g bytes (%s; upper bound for %.4g voxel-triangle pairs, "
                    "%.4g voxels) which exceeds the memory limit of %" PRIu64
                    " bytes (%s); lower the depth or raise the limit (--memory-limit)",
                    options.depth, est.bytes, bytes_text(est.bytes).c_str(), est.pair_bound, est.voxel_bound,
                    st.memory_limit, bytes_text(static_cast<double>(st.memory_limit)).c_str());
      throw Error(buf);
    }

    // 3. prepare: triangles in Morton order of their centroids (then by index), so a brick's
    // triangles are close in memory; the order is fixed, so sums per voxel stay deterministic.
    const Snapper snap(chk.grid);
    std::vector<std::pair<uint64_t, uint32_t>> order(chk.triangles);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, chk.triangles, 4096), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t t = r.begin(); t < r.end(); ++t) {
        int64_t l[3][3];
        for (int i = 0; i < 3; ++i) snap(input.positions[input.indices[3 * t + i]], l[i]);
        uint32_t c[3];
        for (int k = 0; k < 3; ++k)
          c[k] = static_cast<uint32_t>(std::min<int64_t>((l[0][k] + l[1][k] + l[2][k]) / 3 >> (kLatticeBits - kMaxVoxelDepth),
                                                         (int64_t{1} << kMaxVoxelDepth) - 1));
        order[t] = {morton_encode(c[0], c[1], c[2]), static_cast<uint32_t>(t)};
      }
    });
    tbb::parallel_sort(order.begin(), order.end());
    std::vector<TriBox> tris(chk.triangles);
    std::vector<Vec3> normals(chk.triangles);
    std::vector<uint32_t> original(chk.triangles);
    const uint64_t degenerate = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, chk.triangles, 2048), uint64_t{0},
        [&](const tbb::blocked_range<size_t>& r, uint64_t acc) {
          for (size_t t = r.begin(); t < r.end(); ++t) {
            const uint32_t src = order[t].second;
            original[t] = src;
            int64_t l[3][3];
            const Vec3& a = input.positions[input.indices[3 * size_t{src}]];
            const Vec3& b = input.positions[input.indices[3 * size_t{src} + 1]];
            const Vec3& c = input.positions[input.indices[3 * size_t{src} + 2]];
            snap(a, l[0]);
            snap(b, l[1]);
            snap(c, l[2]);
            voxel::prepare(tris[t], l[0], l[1], l[2]);
            if (tris[t].n[0] == 0 && tris[t].n[1] == 0 && tris[t].n[2] == 0) ++acc;
            const double e0[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
            const double e1[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
            const double n[3] = {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2],
                                 e0[0] * e1[1] - e0[1] * e1[0]};
            const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            normals[t] = len > 0.0 && std::isfinite(len)
                             ? Vec3{static_cast<float>(n[0] / len), static_cast<float>(n[1] / len),
                                    static_cast<float>(n[2] / len)}
                             : Vec3{};
          }
          return acc;
        },
        [](uint64_t x, uint64_t y) { return x + y; });
    std::vector<std::pair<uint64_t, uint32_t>>().swap(order);
    st.degenerate_triangles = degenerate;
    st.prepare_ms = total.ms();

    // 4. bin into bricks.
    Timer phase;
    const Tests tests = make_tests(options.strategy, options.depth);
    constexpr size_t kBlock = 1024;
    const size_t blocks = (chk.triangles + kBlock - 1) / kBlock;
    std::vector<std::vector<BinEntry>> block_bins(blocks);
    tbb::enumerable_thread_specific<Counters> bin_counters;
    tbb::parallel_for(size_t{0}, blocks, [&](size_t bi) {
      Counters& c = bin_counters.local();
      std::vector<BinEntry>& out = block_bins[bi];
      const size_t t0 = bi * kBlock, t1 = std::min(chk.triangles, t0 + kBlock);
      for (size_t t = t0; t < t1; ++t) {
        const uint32_t tri = static_cast<uint32_t>(t);
        if (chk.brick_level == 0) {
          out.push_back({0, tri});
          continue;
        }
        auto emit = [&](uint32_t x, uint32_t y, uint32_t z) { out.push_back({morton_encode(x, y, z), tri}); };
        tests.descend(tris[t], 0, 0, 0, 0, chk.brick_level, c, emit);
      }
    });
    size_t nbins = 0;
    std::vector<size_t> offsets(blocks + 1, 0);
    for (size_t b = 0; b < blocks; ++b) offsets[b + 1] = offsets[b] + block_bins[b].size();
    nbins = offsets[blocks];
    std::vector<BinEntry> bins(nbins);
    tbb::parallel_for(size_t{0}, blocks, [&](size_t b) {
      std::copy(block_bins[b].begin(), block_bins[b].end(), bins.begin() + static_cast<std::ptrdiff_t>(offsets[b]));
      std::vector<BinEntry>().swap(block_bins[b]);
    });
    tbb::parallel_sort(bins.begin(), bins.end());
    // Brick ranges.
    std::vector<size_t> brick_start;
    for (size_t i = 0; i < nbins; ++i)
      if (i == 0 || bins[i].brick != bins[i - 1].brick) brick_start.push_back(i);
    const size_t nbricks = brick_start.size();
    brick_start.push_back(nbins);
    st.bricks = nbricks;
    st.bin_ms = phase.ms();

    // 5. bricks.
    phase.reset();
    const Context cx{input, options, chk, tests, tris, normals, original, kLatticeBits - options.depth};
    const size_t local_voxels = size_t{1} << (3 * chk.brick_bits);
    tbb::enumerable_thread_specific<Scratch> scratch([&] {
      Scratch s;
      s.slot_of.assign(local_voxels, kNoSlot);
      return s;
    });
    std::vector<BrickOut> outs(nbricks);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nbricks, 1), [&](const tbb::blocked_range<size_t>& r) {
      Scratch& s = scratch.local();
      for (size_t b = r.begin(); b < r.end(); ++b)
        process_brick(cx, bins[brick_start[b]].brick, bins.data() + brick_start[b], bins.data() + brick_start[b + 1], s,
                      outs[b]);
    });
    std::vector<BinEntry>().swap(bins);
    st.voxel_ms = phase.ms();

    // 6. gather.
    phase.reset();
    std::vector<size_t> voff(nbricks + 1, 0);
    for (size_t b = 0; b < nbricks; ++b) voff[b + 1] = voff[b] + outs[b].codes.size();
    const size_t nvox = voff[nbricks];
    result.grid = chk.grid;
    result.codes.resize(nvox);
    if (options.attributes) result.attrs.resize(nvox);
    tbb::parallel_for(size_t{0}, nbricks, [&](size_t b) {
      const auto at = static_cast<std::ptrdiff_t>(voff[b]);
      std::copy(outs[b].codes.begin(), outs[b].codes.end(), result.codes.begin() + at);
      if (options.attributes) std::copy(outs[b].attrs.begin(), outs[b].attrs.end(), result.attrs.begin() + at);
      std::vector<uint64_t>().swap(outs[b].codes);
      std::vector<VoxelAttributes>().swap(outs[b].attrs);
    });
    st.gather_ms = phase.ms();

    for (const Counters& c : bin_counters) {
      st.aabb_tests += c.aabb;
      st.plane_tests += c.plane;
      st.sat_tests += c.sat;
      st.vertex_hits += c.vertex;
    }
    for (const Scratch& s : scratch) {
      st.aabb_tests += s.counters.aabb;
      st.plane_tests += s.counters.plane;
      st.sat_tests += s.counters.sat;
      st.vertex_hits += s.counters.vertex;
      st.pairs += s.counters.pairs;
    }
  });
  st.voxels = result.codes.size();
  st.bytes = result.codes.size() * sizeof(uint64_t) + result.attrs.size() * sizeof(VoxelAttributes);
  st.ms = total.ms();
  if (stats_out) *stats_out = st;
  return result;
}

}  // namespace specula
