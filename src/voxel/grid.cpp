// Brick voxel grid with Amanatides-Woo DDA traversal (owner: voxel tracers).
//
// Entry (seed 001, section 3.5): the ray is clipped to the grid's box first. The start cell is
// estimated from the entry point and then corrected against the exact plane distances, so that
// on every axis entry <= t_start < exit holds with the same numbers the kernel uses (the
// seed's "random misses" came from trusting floor(o + t d) alone). Stepping (section 3.4)
// recomputes each next boundary directly from its integer plane instead of accumulating a
// t-delta, which keeps the distances bit-identical to the octree's. The largest empty block
// around a cell (an 8^3 brick, or 64^3, 512^3, ... voxels) is crossed in one step
// (GridTraversal::walk).
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <span>
#include <string>
#include <type_traits>

#include "specula/error.h"
#include "specula/voxel_grid.h"
#include "voxel/voxel_brute.h"

namespace specula {

using voxel::CellHit;
using voxel::LocalRay;

namespace {

constexpr int kBrickShift = 3;  ///< bricks of 8^3 voxels: 512 occupancy bits, one cache line
constexpr uint32_t kBrickMask = (1u << kBrickShift) - 1;

uint32_t bricks_per_axis(int depth) { return depth > kBrickShift ? 1u << (depth - kBrickShift) : 1u; }

/// Bit of voxel (x, y, z) in its brick: the low 9 bits of its Morton code (bit i of each
/// coordinate's low three goes to bit 3i + axis), so a brick's voxels in bit order are in the
/// codes' order and a popcount ranks them.
constexpr uint32_t spread_brick(uint32_t v) { return (v & 1u) | (v & 2u) << 2 | (v & 4u) << 4; }
constexpr uint32_t brick_bit(uint32_t x, uint32_t y, uint32_t z) {
  return spread_brick(x & 7u) | spread_brick(y & 7u) << 1 | spread_brick(z & 7u) << 2;
}
static_assert(brick_bit(5, 3, 6) == (morton_encode(5, 3, 6) & 511u), "brick bits follow the Morton order");

/// The Morton code of the brick holding the voxel of Morton code \p code (its bits above the
/// brick's own): sorted codes put a brick's voxels next to each other, bricks in Morton order.
constexpr uint64_t brick_key(uint64_t code) { return code >> (3 * kBrickShift); }

/// Index (x fastest) of the block of 2^shift voxels per side holding voxel (x, y, z), in a level
/// of \p n blocks per axis: the brick table (shift kBrickShift) and the coarse levels.
inline uint64_t block_index(uint32_t x, uint32_t y, uint32_t z, int shift, uint64_t n) {
  return (x >> shift) + n * ((y >> shift) + n * (z >> shift));
}

}  // namespace

uint64_t VoxelGridTracer::table_bytes(int depth) {
  const uint64_t n = bricks_per_axis(std::clamp(depth, 0, kMaxVoxelDepth));
  return n * n * n * sizeof(uint32_t);
}

VoxelGridTracer VoxelGridTracer::build(const VoxelSet& set, const VoxelTracerOptions& options) {
  voxel::validate_set(set, "grid");
  const int depth = set.grid.depth;
  const auto starts_brick = [&set](size_t i) { return i == 0 || brick_key(set.codes[i]) != brick_key(set.codes[i - 1]); };
  uint64_t bricks = 0;
  for (size_t i = 0; i < set.codes.size(); ++i) bricks += starts_brick(i);
  const uint64_t bytes = table_bytes(depth) + bricks * (sizeof(Brick) + sizeof(uint32_t));
  if (bytes > options.max_grid_bytes) {
    char msg[360];
    std::snprintf(msg, sizeof msg,
                  "grid: a voxel grid at depth %d (%u^3 voxels; a table of %llu bricks of 8^3, %llu occupied) needs "
                  "%.2f GiB, over the limit of %.2f GiB (VoxelTracerOptions::max_grid_bytes); use the SVO or a "
                  "smaller depth",
                  depth, set.grid.resolution(), static_cast<unsigned long long>(table_bytes(depth) / sizeof(uint32_t)),
                  static_cast<unsigned long long>(bricks), static_cast<double>(bytes) / 1073741824.0,
                  static_cast<double>(options.max_grid_bytes) / 1073741824.0);
    throw Error(msg);
  }
  VoxelGridTracer g;
  g.grid_ = set.grid;
  g.mode_ = options.mode;
  const uint64_t n = bricks_per_axis(depth);
  g.bricks_per_axis_ = static_cast<uint32_t>(n);
  g.table_.assign(n * n * n, kEmptyBrick);
  g.bricks_.assign(bricks, Brick{});
  g.first_.assign(bricks, 0);
  for (int shift = 2 * kBrickShift; depth - shift >= 1; shift += kBrickShift) {
    Level level{shift, uint64_t{1} << (depth - shift), {}};
    level.bits.assign((level.per_axis * level.per_axis * level.per_axis + 63) / 64, 0);
    g.levels_.insert(g.levels_.begin(), std::move(level));
  }
  uint32_t slot = kEmptyBrick;
  for (size_t i = 0; i < set.codes.size(); ++i) {
    uint32_t x, y, z;
    morton_decode(set.codes[i], x, y, z);
    if (starts_brick(i)) {
      ++slot;
      g.table_[block_index(x, y, z, kBrickShift, n)] = slot;
      g.first_[slot] = static_cast<uint32_t>(i);
      for (Level& level : g.levels_) {  // (a block is occupied when one of its bricks is)
        const uint64_t k = block_index(x, y, z, level.shift, level.per_axis);
        level.bits[k >> 6] |= uint64_t{1} << (k & 63u);
      }
    }
    const uint32_t b = brick_bit(x, y, z);
    g.bricks_[slot].bits[b >> 6] |= uint64_t{1} << (b & 63u);
  }
  g.attrs_ = voxel::attributes_or_default(set);
  return g;
}

bool VoxelGridTracer::occupied(uint32_t x, uint32_t y, uint32_t z) const {
  const uint64_t res = grid_.resolution();
  if (x >= res || y >= res || z >= res || table_.empty()) return false;
  const uint32_t slot = table_[block_index(x, y, z, kBrickShift, bricks_per_axis_)];
  if (slot == kEmptyBrick) return false;
  const uint32_t b = brick_bit(x, y, z);
  return (bricks_[slot].bits[b >> 6] >> (b & 63u)) & 1u;
}

size_t VoxelGridTracer::memory_bytes() const {
  size_t bytes = table_.size() * sizeof(uint32_t) + bricks_.size() * sizeof(Brick) + first_.size() * sizeof(uint32_t) +
                 attrs_.size() * sizeof(VoxelAttributes);
  for (const Level& level : levels_) bytes += level.bits.size() * sizeof(uint64_t);
  return bytes;
}

const VoxelAttributes& VoxelGridTracer::attributes(uint32_t prim) const {
  if (prim >= attrs_.size())
    throw Error("grid: prim " + std::to_string(prim) + " out of range (" + std::to_string(attrs_.size()) + " voxels)");
  return attrs_[prim];
}

/// Calls f(std::integral_constant<int, i>) for the axes i = 0, 1, 2: every per-axis array of the
/// walk is then indexed by constants only, and the compiler keeps it in registers.
template <class F>
inline __attribute__((always_inline)) void for_axes(F&& f) {
  f(std::integral_constant<int, 0>{});
  f(std::integral_constant<int, 1>{});
  f(std::integral_constant<int, 2>{});
}

class GridTraversal {
 public:
  /// Visits the occupied voxels the ray crosses, in ray order; leaf(lr, cell, attrs, index)
  /// returns true to stop.
  template <bool kStats, class Leaf>
  static void walk(const VoxelGridTracer& g, const Ray& ray, TraceStats& stats, Leaf&& leaf) {
    if constexpr (kStats) ++stats.rays;
    LocalRay r;
    if (g.attrs_.empty() || !voxel::make_local_ray(ray, g.grid_, r)) return;
    const uint32_t res = g.grid_.resolution();
    const float fres = static_cast<float>(res);
    const auto plane_t = [&r](uint32_t plane, int i) { return (static_cast<float>(plane) - r.o[i]) * r.inv[i]; };
    const auto fixed = [&r](int i) { return ((r.fixed >> i) & 1u) != 0; };
    const auto neg = [&r](int i) { return ((r.mirror >> i) & 1u) != 0; };

    // Clip to the grid box.
    float t0[3], t1[3];
    bool out = false;
    for_axes([&](auto axis) {
      constexpr int i = decltype(axis)::value;
      if (fixed(i)) {
        out = out || !(0.0f <= r.o[i] && r.o[i] < fres);
        t0[i] = -kInf;
        t1[i] = kInf;
      } else {
        t0[i] = plane_t(neg(i) ? res : 0u, i);
        t1[i] = plane_t(neg(i) ? 0u : res, i);
      }
    });
    if (out) return;
    const float tstart = std::max(std::max(t0[0], t0[1]), std::max(t0[2], r.tmin));
    if (!(tstart < std::min(std::min(t1[0], t1[1]), std::min(t1[2], r.tmax)))) return;

    // Places moving axis i in the cell of [lo, hi] where entry plane <= t < exit plane (exact
    // distances): estimated from o + t d, then corrected against the planes. Where rounding
    // makes neighbouring planes equal it is the cell the one-step walk stops in (the last one
    // entered by t), whatever the estimate.
    uint32_t c[3];
    float tprev[3], tnext[3];
    const auto place = [&](int i, float t, uint32_t lo, uint32_t hi) {
      const float est = r.o[i] + t * r.d[i];
      uint32_t ci = !(est > static_cast<float>(lo)) ? lo : est >= static_cast<float>(hi) ? hi : static_cast<uint32_t>(est);
      if (!neg(i)) {
        while (ci > lo && plane_t(ci, i) > t) --ci;
        while (ci < hi && plane_t(ci + 1, i) <= t) ++ci;
        tprev[i] = plane_t(ci, i);
        tnext[i] = plane_t(ci + 1, i);
      } else {
        while (ci < hi && plane_t(ci + 1, i) > t) ++ci;
        while (ci > lo && plane_t(ci, i) <= t) --ci;
        tprev[i] = plane_t(ci + 1, i);
        tnext[i] = plane_t(ci, i);
      }
      c[i] = ci;
    };
    // Start cell.
    for_axes([&](auto axis) {
      constexpr int i = decltype(axis)::value;
      if (fixed(i)) {
        c[i] = static_cast<uint32_t>(std::floor(r.o[i]));
        tprev[i] = -kInf;
        tnext[i] = kInf;
      } else {
        place(i, tstart, 0u, res - 1);
      }
    });

    // Continues from where the ray leaves the empty block of 2^shift voxels per side around its
    // cell: the nearest of the block's exit planes (exact distances, like every boundary), in
    // the cell the one-voxel walk would reach there. The cells it skips are empty, or touched
    // only at that distance (zero length: never reported), so nothing changes. False: the ray
    // ends (tmax) or leaves the grid in the block.
    const auto leave_block = [&](int shift) {
      float texit = kInf;
      for_axes([&](auto axis) {
        constexpr int i = decltype(axis)::value;
        if (fixed(i)) return;
        const uint32_t plane = neg(i) ? c[i] >> shift << shift : std::min(((c[i] >> shift) + 1) << shift, res);
        texit = std::min(texit, plane_t(plane, i));
      });
      if (texit >= r.tmax) return false;
      // Each axis whose next boundary is within texit moves on, past its current cell.
      bool inside = true;
      for_axes([&](auto axis) {
        constexpr int i = decltype(axis)::value;
        if (!inside || fixed(i) || tnext[i] > texit) return;
        if (plane_t(neg(i) ? 0u : res, i) <= texit) {  // leaves the grid
          inside = false;
          return;
        }
        // (tnext <= texit < the grid's exit: there is a cell beyond c on this axis.)
        if (neg(i)) place(i, texit, 0u, c[i] - 1);
        else place(i, texit, c[i] + 1, res - 1);
      });
      return inside;
    };

    const uint32_t* table = g.table_.data();
    const VoxelGridTracer::Brick* bricks = g.bricks_.data();
    const uint64_t n = g.bricks_per_axis_;
    uint32_t slot = VoxelGridTracer::kEmptyBrick;  // the occupied brick of the cell, once looked up
    bool new_brick = true;
    for (;;) {
      if constexpr (kStats) ++stats.nodes_visited;
      if (new_brick) {
        // The largest empty block around the cell, coarsest level first.
        int empty = 0;
        for (const VoxelGridTracer::Level& level : g.levels_) {
          const uint64_t k = block_index(c[0], c[1], c[2], level.shift, level.per_axis);
          if (!((level.bits[k >> 6] >> (k & 63u)) & 1u)) {
            empty = level.shift;
            break;
          }
        }
        slot = empty != 0 ? VoxelGridTracer::kEmptyBrick
                          : table[block_index(c[0], c[1], c[2], kBrickShift, n)];
        if (slot == VoxelGridTracer::kEmptyBrick) {
          if (!leave_block(empty != 0 ? empty : kBrickShift)) return;
          continue;
        }
        new_brick = false;
      }
      const uint32_t b = brick_bit(c[0], c[1], c[2]);
      const uint64_t* bits = bricks[slot].bits;
      if ((bits[b >> 6] >> (b & 63u)) & 1u) {
        const float te = std::max(std::max(tprev[0], tprev[1]), std::max(tprev[2], r.tmin));
        const float tx = std::min(std::min(tnext[0], tnext[1]), std::min(tnext[2], r.tmax));
        if (te < tx) {
          if constexpr (kStats) ++stats.triangles_tested;
          // Attribute index: the brick's first voxel's, plus the voxels before this one in it.
          uint32_t index = g.first_[slot];
          for (uint32_t w = 0; w < (b >> 6); ++w) index += static_cast<uint32_t>(std::popcount(bits[w]));
          index += static_cast<uint32_t>(std::popcount(bits[b >> 6] & ((uint64_t{1} << (b & 63u)) - 1)));
          const uint32_t cell[3] = {c[0], c[1], c[2]};  // a copy: c itself stays in registers
          if (leaf(r, cell, g.attrs_[index], index)) return;
        }
      }
      // One step along the axis whose next boundary is nearest (ties: the lowest axis).
      bool done = false;
      const auto step = [&](auto axis) {
        constexpr int k = decltype(axis)::value;
        if (tnext[k] >= r.tmax) {
          done = true;
        } else if (neg(k)) {
          if (c[k] == 0) {
            done = true;
            return;
          }
          --c[k];
          tprev[k] = tnext[k];
          tnext[k] = plane_t(c[k], k);
          new_brick = (c[k] & kBrickMask) == kBrickMask;
        } else {
          if (c[k] + 1 >= res) {
            done = true;
            return;
          }
          ++c[k];
          tprev[k] = tnext[k];
          tnext[k] = plane_t(c[k] + 1, k);
          new_brick = (c[k] & kBrickMask) == 0;
        }
      };
      if (tnext[0] <= tnext[1]) {
        if (tnext[2] < tnext[0]) step(std::integral_constant<int, 2>{});
        else step(std::integral_constant<int, 0>{});
      } else {
        if (tnext[2] < tnext[1]) step(std::integral_constant<int, 2>{});
        else step(std::integral_constant<int, 1>{});
      }
      if (done) return;
    }
  }
};

void VoxelGridTracer::intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip,
                                         std::span<Hit> hits, TraceStats* stats,
                                         std::span<const uint32_t> skip_prim) const {
  if (hits.size() < rays.size()) throw Error("grid: hits span smaller than rays span");
  if (!skip.empty() && skip.size() < rays.size()) throw Error("grid: skip span smaller than rays span");
  if (!skip_prim.empty() && skip_prim.size() < rays.size()) throw Error("grid: skip_prim span smaller than rays span");
  TraceStats local;
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit hit;
    const uint32_t skip_material = skip.empty() ? kNoHit : skip[i];
    const uint32_t skip_voxel = skip_prim.empty() ? kNoHit : skip_prim[i];
    const auto visit = [&](const LocalRay& r, const uint32_t* cell, const VoxelAttributes& attrs, uint32_t prim) {
      CellHit h;
      if (attrs.material == skip_material || prim == skip_voxel || !voxel::hit_cell(r, cell, attrs, mode_, h)) return false;
      hit.t = h.t;
      hit.prim = prim;
      hit.ng = h.n;
      return true;
    };
    if (stats) GridTraversal::walk<true>(*this, rays[i], local, visit);
    else GridTraversal::walk<false>(*this, rays[i], local, visit);
    hits[i] = hit;
  }
  if (stats) *stats += local;
}

void VoxelGridTracer::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("grid: output span smaller than rays span");
  TraceStats local;
  for (size_t i = 0; i < rays.size(); ++i) {
    Vec3 tr{1.0f, 1.0f, 1.0f};
    const auto visit = [&](const LocalRay& r, const uint32_t* cell, const VoxelAttributes& attrs, uint32_t) {
      CellHit h;
      if (!voxel::hit_cell(r, cell, attrs, mode_, h)) return false;
      if (!(attrs.transparency > 0.0f)) {
        tr = Vec3{};
        return true;
      }
      tr *= Vec3(attrs.transparency);
      return false;
    };
    if (stats) GridTraversal::walk<true>(*this, rays[i], local, visit);
    else GridTraversal::walk<false>(*this, rays[i], local, visit);
    out[i] = tr;
  }
  if (stats) *stats += local;
}

}  // namespace specula
