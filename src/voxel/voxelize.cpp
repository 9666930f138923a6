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
///     Morton code; bricks run in code order and each output is appended to the set as soon
///     as the bricks before it are, so the set is sorted and never copied.
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
#include <atomic>
#include <bit>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <new>
#include <span>
#include <string>
#include <type_traits>
#include <utility>

#include "core/memory.h"
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
  if (clip_shortcut) s += ", clip shortcut";
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

/// A vertex on the integer lattice of tri_box.h: [0, 2^29] per axis over the root cube.
using LatticePoint = std::array<int32_t, 3>;

/// Vertex -> lattice coordinates. Non-finite input (only possible for vertices no triangle
/// uses: check() rejects the others) maps to 0.
struct Snapper {
  double origin[3];
  double scale;
  explicit Snapper(const VoxelGrid& g)
      : origin{g.origin.x, g.origin.y, g.origin.z}, scale(static_cast<double>(kLatticeSide) / g.side) {}
  LatticePoint operator()(const Vec3& p) const {
    LatticePoint out;
    for (int k = 0; k < 3; ++k) {
      const double v = std::nearbyint((static_cast<double>(p[k]) - origin[k]) * scale);
      // Vertices on the far side can land a rounding step outside (the side is a float).
      out[k] = v >= 0.0 ? (v <= static_cast<double>(kLatticeSide) ? static_cast<int32_t>(v) : int32_t{1} << kLatticeBits)
                        : 0;
    }
    return out;
  }
};

/// Every position snapped to the lattice (positions no triangle uses included: cheaper than
/// finding them, and as many as the positions).
std::vector<LatticePoint> snap_positions(const VoxelizeInput& in, const VoxelGrid& grid) {
  const Snapper snap(grid);
  std::vector<LatticePoint> out(in.positions.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, out.size(), 8192), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i) out[i] = snap(in.positions[i]);
  });
  return out;
}

/// The lattice vertices of triangle \p t.
struct LatticeTri {
  int64_t v[3][3];
  LatticeTri(const VoxelizeInput& in, const std::vector<LatticePoint>& lat, size_t t) {
    for (int i = 0; i < 3; ++i) {
      const LatticePoint& p = lat[in.indices[3 * t + i]];
      for (int k = 0; k < 3; ++k) v[i][k] = p[k];
    }
  }
};

/// Sizes that the memory estimate multiplies.
struct PerVoxelBytes {
  static constexpr double code = sizeof(uint64_t);
  static constexpr double attrs = sizeof(VoxelAttributes);
};

/// The lattice bounding box of triangle \p l: per axis its smallest and largest coordinate.
struct LatticeBounds {
  int64_t lo[3], hi[3];
  explicit LatticeBounds(const LatticeTri& l) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min({l.v[0][k], l.v[1][k], l.v[2][k]});
      hi[k] = std::max({l.v[0][k], l.v[1][k], l.v[2][k]});
    }
  }
};

/// The volume of a triangle with lattice vertices \p l (in voxel units: \p scale = 2^-shift
/// voxels per lattice unit) grown by a voxel diagonal r = sqrt(3): Steiner's 2 r A + pi r^2 P / 2
/// + 4/3 pi r^3, which contains every voxel the triangle touches. Out of line: the estimate's
/// loop then inlines the box count, which is all the quick estimate needs (called out of line
/// with both, the loop ran at half its speed).
[[gnu::noinline]] double steiner_bound(const int64_t (&l)[3][3], double scale) {
  double a[3], b[3], c[3];
  for (int k = 0; k < 3; ++k) {
    a[k] = static_cast<double>(l[0][k]) * scale;
    b[k] = static_cast<double>(l[1][k]) * scale;
    c[k] = static_cast<double>(l[2][k]) * scale;
  }
  const double e0[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  const double e1[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  const double e2[3] = {c[0] - b[0], c[1] - b[1], c[2] - b[2]};
  const double cr[3] = {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2], e0[0] * e1[1] - e0[1] * e1[0]};
  const double area = 0.5 * std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
  auto len = [](const double* e) { return std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]); };
  const double perimeter = len(e0) + len(e1) + len(e2);
  const double r = std::sqrt(3.0);
  return 2.0 * r * area + 0.5 * 3.14159265358979 * r * r * perimeter + 4.0 / 3.0 * 3.14159265358979 * r * r * r;
}

/// Upper bound of the number of voxels that a triangle with lattice vertices \p l (bounding box
/// \p box) can touch in a grid of \p res voxels per axis of 2^shift lattice units each (\p scale
/// = 2^-shift): the smaller of its bounding-box voxel count (closed boxes: a range [lo, hi]
/// touches floor(hi) - ceil(lo) + 2 voxels at most) and its Steiner volume (steiner_bound).
/// Without \p refine, the box count alone (integers only; a looser bound).
inline double touched_bound(const int64_t (&l)[3][3], const LatticeBounds& box, int shift, double scale, double res,
                            bool refine) {
  // The box on the lattice integers: lo / 2^shift has the same ceil and floor as the double
  // lo * scale (scale = 2^-shift, exact), so this is the double formula without rounding.
  const int64_t cells = static_cast<int64_t>(res);
  double count = 1.0;
  for (int k = 0; k < 3; ++k) {
    const int64_t first = std::max<int64_t>(0, ((box.lo[k] + (int64_t{1} << shift) - 1) >> shift) - 1);
    const int64_t last = std::min<int64_t>(cells - 1, box.hi[k] >> shift);
    count *= static_cast<double>(std::max<int64_t>(1, last - first + 1));
  }
  // The Steiner volume is at least 4/3 pi r^3 > 21.7: small boxes need no square roots.
  if (count <= 21.0 || !refine) return count;
  return std::ceil(std::min(count, steiner_bound(l, scale)));
}

struct Estimate {
  double pair_bound = 0;        ///< (voxel, triangle) incidences
  double brick_pair_bound = 0;  ///< (brick, triangle) incidences
  double voxel_bound = 0;
  double bytes = 0;
};

/// A vertex (x, y, z, 0) in one vector, so a copy or an interpolation is one operation per half
/// (SSE2) or one (AVX).
typedef double Vertex4 __attribute__((vector_size(32)));
/// A clipped part's vertex as stored for the contours: (x, y, z, 0) in floats, converted to and
/// from a Vertex4 in one operation (each lane rounds exactly as a scalar conversion would).
typedef float Float4 __attribute__((vector_size(16)));
// Per-brick scratch sizes used by the estimate and by the code.
/// Sums of one voxel: weighted by the parts' areas; when every part has zero area (the
/// triangles only touch the voxel) the same fields hold unweighted sums (see process_brick).
/// 4 doubles without the vector's 32-byte alignment (members of Slot, kept in a std::vector).
typedef double Double4u __attribute__((vector_size(32), aligned(8)));
struct Slot {
  /// Sums of w * (nx, ny, nz, 1), w * (r, g, b, reflectivity) and w * (transparency, ior, 0, 0)
  /// over the voxel's parts (w = area), updated one vector each (each lane rounds as the scalar
  /// sum would); lane 3 of `nw` is the total weight.
  Double4u nw = {0, 0, 0, 0}, col = {0, 0, 0, 0}, ti = {0, 0, 0, 0};
  uint32_t count = 0;
  float best_area = 0.0f;  ///< meaningful once count > 0
  uint32_t best_tri = 0;
  double cmin = 0, cmax = 0;
  uint32_t verts = 0;
  float normal[3] = {0, 0, 0};  ///< set when the brick's sums are complete
};
// A fresh slot is all zero bits: the slots of a brick are cleared by one memset after it.
static_assert(std::is_trivially_copyable_v<Slot>, "slots are cleared with memset");
struct PairRec {
  uint32_t slot;
  uint32_t tri;
  uint32_t vfirst;  ///< first vertex of the triangle's part (clipped polygon) in Scratch::verts
  uint32_t vcount;
};
/// Brick levels up to which the bins are sorted with one counter per brick (8^6 = 262,144
/// counters; depths up to 11), above which by comparison.
constexpr int kDenseBrickLevel = 6;
struct BinEntry {
  uint64_t brick;
  uint32_t tri;
  bool operator<(const BinEntry& o) const { return brick != o.brick ? brick < o.brick : tri < o.tri; }
};

/// Bytes of the lattice copy of the positions (allocated before the estimate can be made; it
/// is as large as the positions themselves).
double lattice_bytes(const VoxelizeInput& in) { return static_cast<double>(in.positions.size()) * sizeof(LatticePoint); }

/// \p refine: per triangle the smaller of the box and Steiner bounds (touched_bound), else the
/// box alone: a larger, quicker bound (it skips three square roots per triangle and level).
Estimate estimate(const VoxelizeInput& in, const std::vector<LatticePoint>& lat, const Checked& c,
                  const VoxelizeOptions& o, bool refine) {
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
          const LatticeTri l(in, lat, t);
          const LatticeBounds box(l);
          acc.pairs += touched_bound(l.v, box, kLatticeBits - o.depth, to_leaf, leaf_res, refine);
          acc.brick_pairs += touched_bound(l.v, box, kLatticeBits - c.brick_level, to_brick, brick_res, refine);
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
  const double per_voxel = PerVoxelBytes::code + (o.attributes ? PerVoxelBytes::attrs : 0.0);
  const double brick_voxels = std::ldexp(1.0, 3 * c.brick_bits);
  e.bytes = lattice_bytes(in)                                       // snapped positions
            + 2.0 * e.brick_pair_bound * sizeof(BinEntry)           // bins (+ sort buffer)
            + 2.0 * e.voxel_bound * per_voxel                       // the set + waiting brick outputs
            + c.threads * brick_voxels * (sizeof(uint32_t) + (o.attributes ? sizeof(Slot) : 4.0));
  if (o.attributes)  // pair records and clipped polygons of the bricks in flight
    e.bytes += std::min(e.pair_bound, c.threads * brick_voxels * 8.0) * (sizeof(PairRec) + 9 * sizeof(Float4));
  return e;
}

/// The estimate compared with \p limit: the quick (box) bound when it is within the limit
/// (so is the tighter one then, which is never larger), else the tighter bound.
Estimate bound_memory(const VoxelizeInput& in, const std::vector<LatticePoint>& lat, const Checked& c,
                      const VoxelizeOptions& o, uint64_t limit) {
  const Estimate quick = estimate(in, lat, c, o, false);
  return quick.bytes <= static_cast<double>(limit) ? quick : estimate(in, lat, c, o, true);
}

/// The memory limit in force: the option, or the default when it is 0.
uint64_t limit_of(const VoxelizeOptions& o) {
  return o.memory_limit == 0 ? default_voxelize_memory_limit() : o.memory_limit;
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
  uint64_t aabb = 0, plane = 0, sat = 0, vertex = 0, clip = 0, pairs = 0;
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

/// A convex polygon (possibly degenerate). A triangle cut by the 6 planes of a box has at most
/// 9 vertices; splits keep at most kPolyMax (more only arise from rounding, never in practice)
/// and have room for two writes per input vertex, so they write without checks.
constexpr int kPolyMax = 12;
struct Poly {
  int n = 0;
  Vertex4 p[2 * kPolyMax + 2];
};

/// Cuts \p in by the plane x[axis] = c into its closed halves: \p below (x <= c) and
/// \p above (x >= c). Vertices on the plane go to both (a touching polygon stays non-empty).
inline void split(const Poly& in, int axis, double c, Poly& below, Poly& above) {
  // Branch-free: the crossing point is computed for every edge and written at both halves'
  // ends, but only counted when the edge crosses (whether it does is data-dependent, and was
  // the clipping's most mispredicted branch). An edge that does not cross may divide by zero
  // (da == db) or give any other number: its point is never counted, so it is overwritten by
  // the next write or left past the end (floating-point exceptions are not trapped). Counted
  // vertices are the same numbers as a branching loop gives.
  typedef int64_t Lanes4 __attribute__((vector_size(32)));
  const Lanes4 on_axis = {axis == 0 ? -1 : 0, axis == 1 ? -1 : 0, axis == 2 ? -1 : 0, 0};
  const Vertex4 cv = {c, c, c, c};
  Vertex4* pb = below.p;
  Vertex4* pa = above.p;
  const int n = in.n;
  Vertex4 a = in.p[n - 1];
  double da = a[axis] - c;
  for (int i = 0; i < n; ++i) {
    const Vertex4 b = in.p[i];
    const double db = b[axis] - c;
    // The edge a -> b crosses the plane: da and db of strictly opposite signs, i.e. the
    // smaller below 0 and the larger above (the same test as (da < 0 && db > 0) ||
    // (da > 0 && db < 0)). Both comparisons evaluated and combined as integers (&& would
    // branch on the first).
    const int cross = static_cast<int>(std::min(da, db) < 0.0) & static_cast<int>(std::max(da, db) > 0.0);
    const double t = da / (da - db);
    const Vertex4 q = on_axis ? cv : a + (b - a) * t;
    *pb = q;
    *pa = q;
    pb += cross;
    pa += cross;
    *pb = b;
    *pa = b;
    pb += static_cast<int>(db <= 0.0);
    pa += static_cast<int>(db >= 0.0);
    a = b;
    da = db;
  }
  below.n = std::min(static_cast<int>(pb - below.p), kPolyMax);
  above.n = std::min(static_cast<int>(pa - above.p), kPolyMax);
}

/// Cuts \p poly into the slabs [lo + c, lo + c + 1] along \p axis, c = 0 .. count - 1 (what lies
/// outside [lo, lo + count] is dropped), calling piece(c, part) for each non-empty part.
template <class Piece>
inline void slabs(const Poly& poly, int axis, double lo, uint32_t count, Piece&& piece) {
  double mn = poly.p[0][axis], mx = mn;
  for (int i = 1; i < poly.n; ++i) {
    mn = std::min(mn, poly.p[i][axis]);
    mx = std::max(mx, poly.p[i][axis]);
  }
  Poly buf[3];  // rest and spare alternate; buf[2] takes each cut-off part
  const Poly* rest = &poly;
  int spare = 1;
  if (mn < lo) {
    split(poly, axis, lo, buf[2], buf[0]);
    rest = &buf[0];
  }
  // Slabs whose top lies strictly below the polygon: cutting there leaves an empty part below
  // and the polygon unchanged above (every vertex has db > 0), so they are skipped without
  // changing a bit. Pieces of the y and z sweeps start anywhere in the triangle's range, and
  // those cuts were a third of all. The first slab is found from an estimate corrected by
  // exact comparisons (lo + c + 1 is an integer, exact in a double); the last slab is never
  // skipped (its cut also drops what lies beyond the range).
  uint32_t c0 = 0;
  if (mn > lo + 1.0) {
    const double est = std::floor(mn - lo) - 1.0;
    c0 = est >= static_cast<double>(count - 1) ? count - 1 : static_cast<uint32_t>(std::max(est, 0.0));
    while (c0 > 0 && !(lo + static_cast<double>(c0) < mn)) --c0;
    while (c0 + 1 < count && lo + static_cast<double>(c0) + 1.0 < mn) ++c0;
  }
  for (uint32_t c = c0; c < count && rest->n > 0; ++c) {
    const double top = lo + static_cast<double>(c) + 1.0;
    if (mx >= top && c + 1 < count) {
      split(*rest, axis, top, buf[2], buf[spare]);
      rest = &buf[spare];
      spare = rest == &buf[0] ? 1 : 0;
      if (buf[2].n > 0) piece(c, buf[2]);
      continue;
    }
    if (mx > top) {  // the last slab of the range: drop what lies beyond it
      split(*rest, axis, top, buf[2], buf[spare]);
      if (buf[2].n > 0) piece(c, buf[2]);
    } else {
      piece(c, *rest);
    }
    break;
  }
}

/// Twice the signed area of a polygon's projection onto the axes (u, v).
inline double projected_area2(const Poly& q, int u, int v) {
  const double u0 = q.p[0][u], v0 = q.p[0][v];
  double s = 0.0;
  for (int i = 1; i + 1 < q.n; ++i)
    s += (q.p[i][u] - u0) * (q.p[i + 1][v] - v0) - (q.p[i + 1][u] - u0) * (q.p[i][v] - v0);
  return s;
}

/// Unit geometric normal of input triangle \p t (from the unsnapped vertices), or 0 when degenerate.
Vec3 unit_normal(const VoxelizeInput& in, size_t t) {
  const Vec3& a = in.positions[in.indices[3 * t]];
  const Vec3& b = in.positions[in.indices[3 * t + 1]];
  const Vec3& c = in.positions[in.indices[3 * t + 2]];
  const double e0[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
  const double e1[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
  const double n[3] = {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2], e0[0] * e1[1] - e0[1] * e1[0]};
  const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!(len > 0.0) || !std::isfinite(len)) return Vec3{};
  return Vec3{static_cast<float>(n[0] / len), static_cast<float>(n[1] / len), static_cast<float>(n[2] / len)};
}

const TriangleAttributes& attributes_of(const VoxelizeInput& in, size_t t) {
  static const TriangleAttributes kDefault{};
  return in.attributes.empty() ? kDefault : in.attributes[t];
}

/// A triangle's numbers as the vectors Slot sums: (nx, ny, nz, \p one), (r, g, b, reflectivity),
/// (transparency, ior, 0, 0). The floats are converted from a float vector: GCC 12 was seen to
/// skip the rounding to float of an inlined unit_normal() when its components initialise a
/// double vector directly, which changes the sums' last bits.
inline void triangle_vectors(const Vec3& n, const TriangleAttributes& a, Vertex4& nw, Vertex4& col, Vertex4& ti, float one) {
  Float4 f[3] = {{n.x, n.y, n.z, one}, {a.colour.x, a.colour.y, a.colour.z, a.reflectivity}, {a.transparency, a.ior, 0.0f, 0.0f}};
  asm("" : "+m"(f));  // the floats are stored as floats (see above)
  nw = __builtin_convertvector(f[0], Vertex4);
  col = __builtin_convertvector(f[1], Vertex4);
  ti = __builtin_convertvector(f[2], Vertex4);
}

/// The part of the current triangle inside one leaf voxel of its range.
struct Cell {
  uint32_t first = 0;   ///< first vertex in Scratch::verts (relative to the voxel's minimum corner)
  uint16_t count = 0;   ///< vertex count; 0 = no part
  uint16_t inside = 0;  ///< 1: the part certainly meets the voxel's interior (exact tests can be skipped)
  float area = 0.0f;    ///< area of the part, in voxel-side^2 units
};
static_assert(std::is_trivially_copyable_v<Cell>, "cells are cleared with memset");

/// Per-thread scratch of the brick stage.
struct Scratch {
  std::vector<uint32_t> slot_of;  ///< local Morton code -> slot (kNoSlot when untouched)
  /// Local codes touched in this brick, first-touch order: the first ntouched entries (sized
  /// to the brick's voxel count + 1, so a slot is created without a branch).
  std::vector<uint32_t> touched;
  size_t ntouched = 0;
  std::vector<uint64_t> bits;     ///< one bit per local code (all clear between bricks)
  std::vector<uint32_t> sorted;   ///< touched, in increasing order
  std::vector<Slot> slots;  ///< the first ntouched are in use; every later one is all zero
  std::vector<PairRec> pairs;
  std::vector<Float4> verts;  ///< the first nverts are in use: (x, y, z, 0)
  size_t nverts = 0;
  /// The current triangle's parts per leaf voxel of its bounding-box range in the brick.
  std::vector<Cell> cells;
  Counters counters;
};

struct BrickOut {
  std::vector<uint64_t> codes;
  std::vector<VoxelAttributes> attrs;
};

struct Context {
  const VoxelizeInput& in;
  const std::vector<LatticePoint>& lat;  ///< the positions on the lattice
  const VoxelizeOptions& opt;
  const Checked& chk;
  const Tests& tests;
  int leaf_shift = 0;  ///< lattice units per leaf voxel = 2^leaf_shift
};

/// How far inside its voxel (in voxel units) a clipped part's vertex average must lie for the
/// part to certify that the triangle meets the voxel. Each computed vertex is within ~1e-13 of
/// the triangle (a few interpolations of doubles below 2^6), and so is their average (the
/// triangle is convex); a point of the triangle then lies strictly inside the voxel.
constexpr double kInsideMargin = 1e-9;

// Compiled twice (baseline x86-64 and x86-64-v3, i.e. AVX2) with everything it calls inlined,
// the right one chosen at load time: the clipping's 4-double vertices are single AVX registers.
// Both give identical results (no contraction into FMA: -ffp-contract=off).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define SPECULA_VOXELIZE_CLONES [[gnu::flatten, gnu::target_clones("default", "arch=x86-64-v3")]]
#else
#define SPECULA_VOXELIZE_CLONES [[gnu::flatten]]
#endif
SPECULA_VOXELIZE_CLONES
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
  const bool clip_shortcut = attrs && cx.opt.strategy.clip_shortcut;
  const uint32_t res_max = (1u << cx.opt.depth) - 1u;

  s.ntouched = 0;
  s.pairs.clear();
  s.nverts = 0;

  uint32_t cur_tri = 0;
  // The current triangle's (nx, ny, nz, 1), (r, g, b, reflectivity), (transparency, ior, 0, 0).
  Vertex4 cur_nw{}, cur_col{}, cur_ti{};
  size_t zero_area_pairs = 0;  // a voxel can only lack weight if some pair has none
  uint32_t r0[3] = {0, 0, 0}, r1[3] = {0, 0, 0};  // the current triangle's leaf range in the brick
  uint32_t rn[3] = {0, 0, 0};
  auto cell_of = [&](uint32_t X, uint32_t Y, uint32_t Z) -> const Cell& {
    return s.cells[((Z - r0[2]) * rn[1] + (Y - r0[1])) * rn[0] + (X - r0[0])];
  };
  // Records the pair (voxel, current triangle): the voxel's slot, and with attributes the
  // area-weighted sums (in triangle order, as each voxel meets a triangle at most once) and
  // the part's vertices for the contours.
  // \p lcode: the voxel's Morton code in the brick; \p part: the pair's Cell (only read, and
  // then not null, with attributes).
  uint32_t* const slot_of = s.slot_of.data();  // (neither array is resized during a brick)
  uint32_t* const touched = s.touched.data();
  auto accept_code = [&](uint32_t lcode, const Cell* part) {
    ++s.counters.pairs;
    // A new voxel takes the next slot, without a branch (whether a voxel is new is data-
    // dependent and was mispredicted often): the code is written past the end of the touched
    // list and counted only when new.
    const uint32_t old_slot = slot_of[lcode];
    const uint32_t n = static_cast<uint32_t>(s.ntouched);
    const uint32_t is_new = static_cast<uint32_t>(old_slot == kNoSlot);
    const uint32_t new_mask = 0u - is_new;
    const uint32_t slot = (old_slot & ~new_mask) | (n & new_mask);
    slot_of[lcode] = slot;
    touched[n] = lcode;
    s.ntouched += is_new;
    if (!attrs) return;
    if (slot >= s.slots.size()) s.slots.resize(std::max<size_t>(2 * s.slots.size(), 1024));  // zeros
    const Cell& cell = *part;
    const float area = cell.area;
    Slot& sl = s.slots[slot];
    const double w = area;
    zero_area_pairs += area == 0.0f;
    sl.nw += w * cur_nw;
    sl.col += w * cur_col;
    sl.ti += w * cur_ti;
    // The largest part's triangle (the first of equals; the first pair always), selected
    // without a branch (a conditional here compiled to a mispredicted branch).
    const uint32_t larger_mask =
        0u - (static_cast<uint32_t>(area > sl.best_area) | static_cast<uint32_t>(sl.count == 0));
    sl.best_tri = (cur_tri & larger_mask) | (sl.best_tri & ~larger_mask);
    sl.best_area = std::max(sl.best_area, area);  // area >= 0, and best_area is 0 while count is
    ++sl.count;
    s.pairs.push_back({slot, cur_tri, cell.first, cell.count});
  };
  auto local_code = [&](uint32_t X, uint32_t Y, uint32_t Z) {
    return kSpread5[X & bmask] | kSpread5[Y & bmask] << 1 | kSpread5[Z & bmask] << 2;
  };
  // The same from voxel coordinates; \p part looked up when null.
  auto accept = [&](uint32_t X, uint32_t Y, uint32_t Z, const Cell* part = nullptr) {
    accept_code(local_code(X, Y, Z), attrs && part == nullptr ? &cell_of(X, Y, Z) : part);
  };

  // Cuts the triangle into its parts per leaf voxel of the range (slabs along x, then y, then
  // z; each cut is one plane), in brick-local leaf units, and records per part its area (from
  // the projection onto the normal's dominant axis), its vertices relative to the voxel and
  // whether it certainly meets the voxel's interior. Cost ~ the number of parts.
  auto cut_parts = [&](const TriBox& t) {
    // Only the range's cells are cleared (memset: Cell is trivially copyable); the vector
    // keeps its size between triangles.
    const size_t ncells = static_cast<size_t>(rn[0]) * rn[1] * rn[2];
    if (s.cells.size() < ncells) s.cells.resize(ncells);
    std::memset(static_cast<void*>(s.cells.data()), 0, ncells * sizeof(Cell));
    Poly tri;
    tri.n = 3;
    for (int i = 0; i < 3; ++i) {
      tri.p[i][3] = 0.0;
      for (int k = 0; k < 3; ++k)
        tri.p[i][k] = static_cast<double>(t.v[i][k] - (static_cast<int64_t>(base[k]) << F)) * inv_s;
    }
    const double n[3] = {static_cast<double>(t.n[0]), static_cast<double>(t.n[1]), static_cast<double>(t.n[2])};
    const int w = (std::fabs(n[0]) >= std::fabs(n[1]) && std::fabs(n[0]) >= std::fabs(n[2]))
                      ? 0
                      : (std::fabs(n[1]) >= std::fabs(n[2]) ? 1 : 2);
    const int pu = (w + 1) % 3, pv = (w + 2) % 3;
    // area = projected area * |n| / |n_w| (0 for a degenerate triangle: its parts have no area)
    const double area_scale =
        n[w] != 0.0 ? 0.5 * std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) / std::fabs(n[w]) : 0.0;
    double lo[3];
    for (int k = 0; k < 3; ++k) lo[k] = static_cast<double>(r0[k] - base[k]);
    slabs(tri, 0, lo[0], rn[0], [&](uint32_t ix, const Poly& px) {
      slabs(px, 1, lo[1], rn[1], [&](uint32_t iy, const Poly& py) {
        slabs(py, 2, lo[2], rn[2], [&](uint32_t iz, const Poly& q) {
          Cell& cell = s.cells[(static_cast<size_t>(iz) * rn[1] + iy) * rn[0] + ix];
          const int m = q.n;
          if (s.nverts + static_cast<size_t>(m) > s.verts.size()) s.verts.resize(std::max<size_t>(2 * s.verts.size(), 4096));
          cell.first = static_cast<uint32_t>(s.nverts);
          Float4* dst = s.verts.data() + s.nverts;
          s.nverts += static_cast<size_t>(m);
          cell.count = static_cast<uint16_t>(m);
          cell.area = m >= 3 ? static_cast<float>(std::fabs(projected_area2(q, pu, pv)) * area_scale) : 0.0f;
          // Vertices relative to the voxel's minimum corner, and their average for the
          // certificate that the part meets the voxel's interior.
          const Vertex4 o = {lo[0] + ix, lo[1] + iy, lo[2] + iz, 0.0};
          Vertex4 sum = {0, 0, 0, 0};
          for (int i = 0; i < m; ++i) {
            const Vertex4 v = q.p[i] - o;
            dst[i] = __builtin_convertvector(v, Float4);
            sum += v;
          }
          const double lo_sum = kInsideMargin * m, hi_sum = (1.0 - kInsideMargin) * m;
          cell.inside = sum[0] > lo_sum && sum[0] < hi_sum && sum[1] > lo_sum && sum[1] < hi_sum &&
                        sum[2] > lo_sum && sum[2] < hi_sum;
        });
      });
    });
  };

  const bool octree = cx.opt.strategy.traversal == VoxelTraversal::Octree;
  const bool plane_cut = cx.tests.plane_leaf || cx.tests.sat_leaf;
  // A brick's triangles are near in space but not in index order: their indices, attributes
  // and vertices are scattered loads that missed the cache often (a tenth of the brick stage
  // in a profile). They are prefetched a few triangles ahead: the index triple and attributes
  // kAhead entries ahead, the vertices (whose addresses need the indices) half as far.
  constexpr std::ptrdiff_t kAhead = 4;
  const auto prefetch_tri = [&](const BinEntry* ahead) {
    if (last - ahead > kAhead) {
      const uint32_t tri = ahead[kAhead].tri;
      __builtin_prefetch(cx.in.indices.data() + 3 * static_cast<size_t>(tri));
      if (attrs && !cx.in.attributes.empty()) __builtin_prefetch(cx.in.attributes.data() + tri);
    }
    if (last - ahead > kAhead / 2) {
      const uint32_t* idx = cx.in.indices.data() + 3 * static_cast<size_t>(ahead[kAhead / 2].tri);
      for (int i = 0; i < 3; ++i) {
        __builtin_prefetch(cx.lat.data() + idx[i]);
        if (attrs) __builtin_prefetch(cx.in.positions.data() + idx[i]);
      }
    }
  };
  for (const BinEntry* e = first; e != last; ++e) {
    prefetch_tri(e);
    cur_tri = e->tri;
    TriBox t;
    {
      const LatticeTri l(cx.in, cx.lat, cur_tri);
      voxel::prepare(t, l.v[0], l.v[1], l.v[2]);
    }
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
    if (attrs) {
      triangle_vectors(unit_normal(cx.in, cur_tri), attributes_of(cx.in, cur_tri), cur_nw, cur_col, cur_ti, 1.0f);
      cut_parts(t);
    }
    if (octree) {
      cx.tests.descend(t, cx.chk.brick_level, bx, by, bz, cx.opt.depth, s.counters, accept);
      continue;
    }
    auto try_voxel = [&](uint32_t x, uint32_t y, uint32_t z) {
      ++s.counters.aabb;
      const Cell* part = attrs ? &cell_of(x, y, z) : nullptr;
      if (clip_shortcut && part != nullptr && part->inside) {
        ++s.counters.clip;
        accept(x, y, z, part);
        return;
      }
      const LatticeBox box{{static_cast<int64_t>(x) << F, static_cast<int64_t>(y) << F, static_cast<int64_t>(z) << F}, S};
      if (cx.tests.pass(t, box, true, s.counters)) accept(x, y, z, part);
    };
    if (!plane_cut || (t.n[0] == 0 && t.n[1] == 0 && t.n[2] == 0)) {
      for (uint32_t z = r0[2]; z <= r1[2]; ++z)
        for (uint32_t y = r0[1]; y <= r1[1]; ++y)
          for (uint32_t x = r0[0]; x <= r1[0]; ++x) try_voxel(x, y, z);
      continue;
    }
    // Columns along the normal's dominant axis w: only the voxels near the plane's w-range
    // over the column are tried (the exact plane test in pass() still decides, so the range
    // only needs to be a superset: doubles with a slack of 1e-6 voxel).
    const int w = (std::abs(t.n[0]) >= std::abs(t.n[1]) && std::abs(t.n[0]) >= std::abs(t.n[2]))
                      ? 0
                      : (std::abs(t.n[1]) >= std::abs(t.n[2]) ? 1 : 2);
    const int u = (w + 1) % 3, v = (w + 2) % 3;
    const int64_t sg = t.n[w] > 0 ? 1 : -1;
    const double nw = static_cast<double>(sg * t.n[w]);
    // The plane in leaf units: k_w = (D - nu k_u - nv k_v) / nw over a voxel column.
    const double fu = static_cast<double>(sg * t.n[u]) / nw, fv = static_cast<double>(sg * t.n[v]) / nw;
    const double fd = static_cast<double>(static_cast<__int128>(sg) * t.d) / (nw * static_cast<double>(S));
    const double fpos = (fu > 0 ? fu : 0) + (fv > 0 ? fv : 0), fneg = (fu < 0 ? fu : 0) + (fv < 0 ? fv : 0);
    const double wlo = static_cast<double>(r0[w]) - 2.0, whi = static_cast<double>(r1[w]) + 2.0;
    // With the SAT at the leaves, a column whose square the triangle's projection along w
    // misses is skipped whole: that projection's three edge axes are SAT axes, so every voxel
    // of the column would fail edge_overlap() (same integers, same critical corners).
    const bool column_test = cx.tests.sat_leaf;
    const int64_t(*en)[2] = t.en[w];
    const int64_t* ec = t.ec[w];
    int64_t ecs[3];
    for (int i = 0; i < 3; ++i) ecs[i] = ec[i] + t.ecrit[w][i] * S;
    uint32_t q[3];
    // Cells per step along w in the range's cell array.
    const int64_t wstride = w == 0 ? 1 : (w == 1 ? static_cast<int64_t>(rn[0]) : static_cast<int64_t>(rn[0]) * rn[1]);
    for (uint32_t cv = r0[v]; cv <= r1[v]; ++cv)
      for (uint32_t cu = r0[u]; cu <= r1[u]; ++cu) {
        if (column_test) {
          const int64_t pu = static_cast<int64_t>(cu) << F, pv = static_cast<int64_t>(cv) << F;
          if (en[0][0] * pu + en[0][1] * pv + ecs[0] < 0 || en[1][0] * pu + en[1][1] * pv + ecs[1] < 0 ||
              en[2][0] * pu + en[2][1] * pv + ecs[2] < 0)
            continue;
        }
        const double a = fu * cu + fv * cv;
        // kmin = ceil(x) - 1 and kmax = floor(y), clamped to the range first (so the integer
        // conversions below stay in range; truncation then rounds toward zero).
        const double x = std::clamp(fd - (a + fpos) - 1e-6, wlo, whi), y = std::clamp(fd - (a + fneg) + 1e-6, wlo, whi);
        int64_t kmin = static_cast<int64_t>(x), kmax = static_cast<int64_t>(y);
        kmin += static_cast<double>(kmin) < x;  // ceil
        kmin -= 1;
        kmax -= static_cast<double>(kmax) > y;  // floor
        const int64_t k0 = std::max<int64_t>(kmin, r0[w]), k1 = std::min<int64_t>(kmax, r1[w]);
        if (k0 > k1) continue;
        q[u] = cu;
        q[v] = cv;
        // The column's share of the local code and of the cell index, once per column.
        q[w] = r0[w];
        const uint32_t col_code = local_code(q[0], q[1], q[2]) & ~(kSpread5[r0[w] & bmask] << w);
        const Cell* col_cells = attrs ? &cell_of(q[0], q[1], q[2]) - static_cast<int64_t>(r0[w]) * wstride : nullptr;
        for (uint32_t k = static_cast<uint32_t>(k0); k <= static_cast<uint32_t>(k1); ++k) {
          ++s.counters.aabb;
          const uint32_t lcode = col_code | kSpread5[k & bmask] << w;
          const Cell* part = attrs ? col_cells + static_cast<int64_t>(k) * wstride : nullptr;
          if (clip_shortcut && part->inside) {
            ++s.counters.clip;
            accept_code(lcode, part);
            continue;
          }
          q[w] = k;
          const LatticeBox box{{static_cast<int64_t>(q[0]) << F, static_cast<int64_t>(q[1]) << F,
                                static_cast<int64_t>(q[2]) << F},
                               S};
          if (cx.tests.pass(t, box, true, s.counters)) accept_code(lcode, part);
        }
      }
  }

  // Output in Morton order: the touched local codes, read back sorted from a bitmap.
  const std::span<const uint32_t> order(s.touched.data(), s.ntouched);
  const size_t nv = order.size();
  const std::span<Slot> slots(s.slots.data(), attrs ? nv : 0);
  for (const uint32_t code : order) s.bits[code >> 6] |= uint64_t{1} << (code & 63u);
  std::vector<uint32_t>& sorted = s.sorted;
  sorted.clear();
  const size_t words = ((size_t{1} << (3 * bb)) + 63) >> 6;
  for (size_t wi = 0; wi < words; ++wi) {
    for (uint64_t word = s.bits[wi]; word != 0; word &= word - 1)
      sorted.push_back(static_cast<uint32_t>(wi << 6) | static_cast<uint32_t>(std::countr_zero(word)));
    s.bits[wi] = 0;
  }
  const uint64_t high = brick << (3 * bb);
  // reserve + push_back: each output element written once (no value-initialising resize).
  out.codes.reserve(nv);
  for (size_t i = 0; i < nv; ++i) out.codes.push_back(high | sorted[i]);

  if (attrs) {
    // Voxels the triangles only touch (every part has zero area): unweighted sums instead, in
    // the same (triangle) order.
    for (const PairRec& p : zero_area_pairs > 0 ? std::span<const PairRec>(s.pairs) : std::span<const PairRec>()) {
      Slot& sl = s.slots[p.slot];
      if (sl.nw[3] > 0.0) continue;
      Vertex4 nw, col, ti;  // lane 3 of nw 0: the weight stays 0
      triangle_vectors(unit_normal(cx.in, p.tri), attributes_of(cx.in, p.tri), nw, col, ti, 0.0f);
      sl.nw += nw;
      sl.col += col;
      sl.ti += ti;
    }
    for (Slot& sl : slots) {
      const bool weighted = sl.nw[3] > 0.0;
      const double nn[3] = {sl.nw[0], sl.nw[1], sl.nw[2]};

      const double len = std::sqrt(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
      const double scale = weighted ? sl.nw[3] : static_cast<double>(sl.count);
      double nv3[3] = {0, 0, 1};
      if (len > 1e-9 * scale) {
        for (int k = 0; k < 3; ++k) nv3[k] = nn[k] / len;
      } else {  // normals cancel (e.g. two sides of a thin wall): the largest triangle's
        const Vec3 b = unit_normal(cx.in, sl.best_tri);
        if (b != Vec3{}) nv3[0] = b.x, nv3[1] = b.y, nv3[2] = b.z;
      }
      for (int k = 0; k < 3; ++k) sl.normal[k] = static_cast<float>(nv3[k]);
      sl.cmin = std::numeric_limits<double>::infinity();
      sl.cmax = -std::numeric_limits<double>::infinity();
    }
    for (const PairRec& p : s.pairs) {
      Slot& sl = s.slots[p.slot];
      // d = n0 (v0 - 0.5) + n1 (v1 - 0.5) + n2 (v2 - 0.5): the products in one vector.
      const Vertex4 nrm = {sl.normal[0], sl.normal[1], sl.normal[2], 0.0};
      const Vertex4 half = {0.5, 0.5, 0.5, 0.5};
      for (uint32_t i = 0; i < p.vcount; ++i) {
        const Vertex4 prod = (__builtin_convertvector(s.verts[p.vfirst + i], Vertex4) - half) * nrm;
        const double d = prod[0] + prod[1] + prod[2];
        sl.cmin = std::min(sl.cmin, d);
        sl.cmax = std::max(sl.cmax, d);
      }
      sl.verts += p.vcount;
    }
    const double side = static_cast<double>(cx.chk.grid.voxel_size());
    out.attrs.reserve(nv);
    for (size_t i = 0; i < nv; ++i) {
      if (i + 8 < nv) {  // slots are in first-touch order, read here in code order
        const char* ahead = reinterpret_cast<const char*>(&s.slots[s.slot_of[sorted[i + 8]]]);
        __builtin_prefetch(ahead);
        __builtin_prefetch(ahead + 64);
        __builtin_prefetch(ahead + sizeof(Slot) - 1);
      }
      if (i + 4 < nv && !cx.in.attributes.empty())
        __builtin_prefetch(cx.in.attributes.data() + s.slots[s.slot_of[sorted[i + 4]]].best_tri);
      const Slot& sl = s.slots[s.slot_of[sorted[i]]];
      VoxelAttributes a;
      const bool weighted = sl.nw[3] > 0.0;
      const double inv = 1.0 / (weighted ? sl.nw[3] : static_cast<double>(sl.count));
      const double col[3] = {sl.col[0], sl.col[1], sl.col[2]};
      a.normal = {sl.normal[0], sl.normal[1], sl.normal[2]};
      a.colour = {static_cast<float>(col[0] * inv), static_cast<float>(col[1] * inv), static_cast<float>(col[2] * inv)};
      a.reflectivity = static_cast<float>(sl.col[3] * inv);
      a.transparency = static_cast<float>(sl.ti[0] * inv);
      a.ior = static_cast<float>(sl.ti[1] * inv);
      a.material = attributes_of(cx.in, sl.best_tri).material;
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
      out.attrs.push_back(a);
    }
  }
  for (uint32_t code : order) s.slot_of[code] = kNoSlot;
  if (!slots.empty()) std::memset(static_cast<void*>(slots.data()), 0, slots.size_bytes());
}

}  // namespace

uint64_t voxelize_memory_estimate(const VoxelizeInput& input, const VoxelizeOptions& options) {
  const Checked c = check(input, options);
  tbb::task_arena arena(c.threads);
  double b = 0;
  arena.execute([&] { b = bound_memory(input, snap_positions(input, c.grid), c, options, limit_of(options)).bytes; });
  return b >= 1.8e19 ? std::numeric_limits<uint64_t>::max() : static_cast<uint64_t>(b);
}

VoxelSet voxelize(const VoxelizeInput& input, const VoxelizeOptions& options, VoxelizeStats* stats_out) {
  Timer total;
  VoxelizeStats st;
  const Checked chk = check(input, options);
  st.threads = chk.threads;
  st.triangles = chk.triangles;
  st.memory_limit = limit_of(options);
  // \p what: what \p bytes is for.
  auto refuse = [&](double bytes, const char* what) {
    char buf[512];
    std::snprintf(buf, sizeof buf,
                  "voxelize: depth %d would need up to %.4g bytes (%s; %s) which exceeds the memory limit of %" PRIu64
                  " bytes (%s); lower the depth or raise the limit (--memory-limit)",
                  options.depth, bytes, bytes_text(bytes).c_str(), what, st.memory_limit,
                  bytes_text(static_cast<double>(st.memory_limit)).c_str());
    throw Error(buf);
  };
  // The lattice copy of the positions comes first (the estimate needs it): check it alone.
  if (lattice_bytes(input) > static_cast<double>(st.memory_limit)) {
    char what[96];
    std::snprintf(what, sizeof what, "for the lattice copy of the %zu vertices alone", input.positions.size());
    refuse(lattice_bytes(input), what);
  }

  tbb::task_arena arena(chk.threads);
  VoxelSet result;
  arena.execute([&] {
    // 2. snap, estimate and limit.
    const std::vector<LatticePoint> lat = snap_positions(input, chk.grid);
    const Estimate est = bound_memory(input, lat, chk, options, st.memory_limit);
    st.estimate_bytes = est.bytes >= 1.8e19 ? std::numeric_limits<uint64_t>::max() : static_cast<uint64_t>(est.bytes);
    if (est.bytes > static_cast<double>(st.memory_limit)) {
      char what[128];
      std::snprintf(what, sizeof what, "upper bound for %.4g voxel-triangle pairs, %.4g voxels", est.pair_bound,
                    est.voxel_bound);
      refuse(est.bytes, what);
    }
    st.prepare_ms = total.ms();

    // 3-4. bin into bricks: a triangle inside one brick goes there without tests; larger ones
    // descend the implicit octree to the brick level (or test the bricks of their range).
    Timer phase;
    const Tests tests = make_tests(options.strategy, options.depth);
    const bool octree = options.strategy.traversal == VoxelTraversal::Octree;
    const int brick_shift = kLatticeBits - chk.brick_level;
    const int64_t brick_side = int64_t{1} << brick_shift;
    const int64_t brick_max = (int64_t{1} << chk.brick_level) - 1;
    constexpr size_t kBlock = 1024;
    const size_t blocks = (chk.triangles + kBlock - 1) / kBlock;
    std::vector<std::vector<BinEntry>> block_bins(blocks);
    struct BinCounters {
      Counters c;
      uint64_t degenerate = 0;
    };
    tbb::enumerable_thread_specific<BinCounters> bin_counters;
    tbb::parallel_for(size_t{0}, blocks, [&](size_t bi) {
      BinCounters& bc = bin_counters.local();
      std::vector<BinEntry>& out = block_bins[bi];
      const size_t t0 = bi * kBlock, t1 = std::min(chk.triangles, t0 + kBlock);
      out.reserve(t1 - t0 + t1 / 8 - t0 / 8);
      for (size_t t = t0; t < t1; ++t) {
        const uint32_t tri = static_cast<uint32_t>(t);
        const LatticeTri l(input, lat, t);
        const int64_t e0[3] = {l.v[1][0] - l.v[0][0], l.v[1][1] - l.v[0][1], l.v[1][2] - l.v[0][2]};
        const int64_t e1[3] = {l.v[2][0] - l.v[1][0], l.v[2][1] - l.v[1][1], l.v[2][2] - l.v[1][2]};
        if (e0[1] * e1[2] == e0[2] * e1[1] && e0[2] * e1[0] == e0[0] * e1[2] && e0[0] * e1[1] == e0[1] * e1[0])
          ++bc.degenerate;
        if (chk.brick_level == 0) {
          out.push_back({0, tri});
          continue;
        }
        // The bricks of the bounding box (closed boxes, as in process_brick).
        const LatticeBounds bounds(l);
        int64_t b0[3], b1[3];
        for (int k = 0; k < 3; ++k) {
          b0[k] = std::max<int64_t>(((bounds.lo[k] + brick_side - 1) >> brick_shift) - 1, 0);
          b1[k] = std::min<int64_t>(bounds.hi[k] >> brick_shift, brick_max);
        }
        if (!octree && b0[0] == b1[0] && b0[1] == b1[1] && b0[2] == b1[2]) {
          out.push_back({morton_encode(static_cast<uint32_t>(b0[0]), static_cast<uint32_t>(b0[1]),
                                       static_cast<uint32_t>(b0[2])),
                         tri});
          continue;
        }
        TriBox tb;
        voxel::prepare(tb, l.v[0], l.v[1], l.v[2]);
        auto emit = [&](uint32_t x, uint32_t y, uint32_t z) { out.push_back({morton_encode(x, y, z), tri}); };
        if (octree) {
          tests.descend(tb, 0, 0, 0, 0, chk.brick_level, bc.c, emit);
          continue;
        }
        for (int64_t z = b0[2]; z <= b1[2]; ++z)
          for (int64_t y = b0[1]; y <= b1[1]; ++y)
            for (int64_t x = b0[0]; x <= b1[0]; ++x) {
              ++bc.c.aabb;
              const LatticeBox box{{x << brick_shift, y << brick_shift, z << brick_shift}, brick_side};
              if (tests.pass(tb, box, false, bc.c))
                emit(static_cast<uint32_t>(x), static_cast<uint32_t>(y), static_cast<uint32_t>(z));
            }
      }
    });
    size_t nbins = 0;
    std::vector<size_t> offsets(blocks + 1, 0);
    for (size_t b = 0; b < blocks; ++b) offsets[b + 1] = offsets[b] + block_bins[b].size();
    nbins = offsets[blocks];
    std::vector<BinEntry> bins(nbins);
    if (chk.brick_level <= kDenseBrickLevel) {
      // Sorted by brick, then triangle, in two linear passes: the blocks hold their entries in
      // triangle order, so a stable counting sort by brick (one counter per brick of the
      // level) gives the comparison sort's order.
      std::vector<size_t> next(size_t{1} << (3 * chk.brick_level), 0);
      for (const std::vector<BinEntry>& block : block_bins)
        for (const BinEntry& e : block) ++next[e.brick];
      size_t pos = 0;
      for (size_t& c : next) pos += std::exchange(c, pos);
      for (std::vector<BinEntry>& block : block_bins) {
        for (const BinEntry& e : block) bins[next[e.brick]++] = e;
        std::vector<BinEntry>().swap(block);
      }
    } else {
      tbb::parallel_for(size_t{0}, blocks, [&](size_t b) {
        std::copy(block_bins[b].begin(), block_bins[b].end(), bins.begin() + static_cast<std::ptrdiff_t>(offsets[b]));
        std::vector<BinEntry>().swap(block_bins[b]);
      });
      tbb::parallel_sort(bins.begin(), bins.end());
    }
    // Brick ranges.
    std::vector<size_t> brick_start;
    for (size_t i = 0; i < nbins; ++i)
      if (i == 0 || bins[i].brick != bins[i - 1].brick) brick_start.push_back(i);
    const size_t nbricks = brick_start.size();
    brick_start.push_back(nbins);
    st.bricks = nbricks;
    for (const BinCounters& bc : bin_counters) st.degenerate_triangles += bc.degenerate;
    st.bin_ms = phase.ms();

    // 5. bricks.
    phase.reset();
    const Context cx{input, lat, options, chk, tests, kLatticeBits - options.depth};
    const size_t local_voxels = size_t{1} << (3 * chk.brick_bits);
    tbb::enumerable_thread_specific<Scratch> scratch([&] {
      Scratch s;
      const auto fill = [](auto& v, size_t n, auto value) {
        v.reserve(n);
        prepare_for_writes(v.data(), n * sizeof(value));  // all written at once below
        v.assign(n, value);
      };
      fill(s.slot_of, local_voxels, kNoSlot);
      fill(s.touched, local_voxels + 1, uint32_t{0});
      fill(s.bits, (local_voxels + 63) / 64, uint64_t{0});
      return s;
    });
    // Bricks in Morton order, handed out one at a time; each output is appended to the result
    // in that order as soon as its predecessors are (by whichever thread finds it next in
    // line), so the set is built while the bricks run, from outputs still in cache, and the
    // outputs' buffers are reused: no second copy of the set is ever allocated. The result's
    // capacity is the voxel bound of the estimate (address space only: pages are touched as
    // voxels arrive); it stays that large.
    result.grid = chk.grid;
    try {
      // (1e15 voxels: far beyond any address space, and below every max_size() here.)
      const double bound = std::min(est.voxel_bound, 1e15);
      result.codes.reserve(static_cast<size_t>(bound));
      if (options.attributes) result.attrs.reserve(static_cast<size_t>(bound));
      prepare_for_writes(result.codes.data(), result.codes.capacity() * sizeof(uint64_t));
      prepare_for_writes(result.attrs.data(), result.attrs.capacity() * sizeof(VoxelAttributes));
    } catch (const std::bad_alloc&) {  // no such address space (--no-memory-limit): grow instead
    }
    std::mutex mu;
    std::vector<std::unique_ptr<BrickOut>> done(nbricks);  // finished, waiting for their turn
    std::vector<std::unique_ptr<BrickOut>> spare;          // emptied outputs, capacity kept
    size_t appended = 0;                                   // bricks in the result so far
    bool appending = false;                                // some thread is appending
    std::atomic<size_t> next_brick{0};
    tbb::parallel_for(0, chk.threads, [&](int /*worker*/) {
      Scratch& s = scratch.local();
      for (size_t b = next_brick.fetch_add(1, std::memory_order_relaxed); b < nbricks;
           b = next_brick.fetch_add(1, std::memory_order_relaxed)) {
        std::unique_ptr<BrickOut> out;
        {
          const std::lock_guard<std::mutex> lock(mu);
          if (!spare.empty()) {
            out = std::move(spare.back());
            spare.pop_back();
          }
        }
        if (!out) out = std::make_unique<BrickOut>();
        out->codes.clear();
        out->attrs.clear();
        process_brick(cx, bins[brick_start[b]].brick, bins.data() + brick_start[b], bins.data() + brick_start[b + 1], s,
                      *out);
        std::unique_ptr<BrickOut> next;
        {
          const std::lock_guard<std::mutex> lock(mu);
          done[b] = std::move(out);
          if (appending || !done[appended]) continue;  // not this thread's turn to append
          appending = true;
          next = std::move(done[appended]);
        }
        // This thread appends every finished brick next in line (the check for the next one
        // and giving up the role happen under the lock, so none is left behind).
        while (next) {
          result.codes.insert(result.codes.end(), next->codes.begin(), next->codes.end());
          if (options.attributes) result.attrs.insert(result.attrs.end(), next->attrs.begin(), next->attrs.end());
          // `appended` changes only in the appending thread, which this is.
          if (options.progress) options.progress(static_cast<double>(appended + 1) / static_cast<double>(nbricks));
          const std::lock_guard<std::mutex> lock(mu);
          spare.push_back(std::move(next));
          next.reset();
          ++appended;
          if (appended < nbricks && done[appended])
            next = std::move(done[appended]);
          else
            appending = false;
        }
      }
    });
    std::vector<BinEntry>().swap(bins);
    st.voxel_ms = phase.ms();
    if (appended != nbricks) throw Error("voxelize: internal error: bricks left unappended");

    for (const BinCounters& bc : bin_counters) {
      st.aabb_tests += bc.c.aabb;
      st.plane_tests += bc.c.plane;
      st.sat_tests += bc.c.sat;
      st.vertex_hits += bc.c.vertex;
    }
    for (const Scratch& s : scratch) {
      st.aabb_tests += s.counters.aabb;
      st.plane_tests += s.counters.plane;
      st.sat_tests += s.counters.sat;
      st.vertex_hits += s.counters.vertex;
      st.clip_accepts += s.counters.clip;
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
