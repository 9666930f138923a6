// Sparse voxel octree traversal: closest hit and transmittance (owner: voxel tracers).
//
// Revelles et al.'s parametric traversal as seed 000 extends it. Per node (one stack frame
// per level): the distances t0 / t1 at which the ray crosses the node's near / far plane of
// each axis, and tm at which it crosses the mid plane, all computed as (integer plane - o) *
// (1 / d) in the grid's local frame, exactly as the shared kernel (voxel_brute.h) computes
// voxel boundaries, so the nodes visited and the hits found are bit-identical to the grid's
// and the brute force's. Directions are mirrored to positive: child slots are numbered along
// the ray (bit i set = the far half of axis i) and `slot ^ mirror` is the real child index.
// The first child has bit i set when the mid plane i is crossed at or before the node's entry
// distance; the following ones cross the remaining mid planes inside the node in increasing tm
// order. That list (at most 4 slots) is built once per node from the three sorted tm values,
// filtered by the child mask and kept in the node's frame (4 bits per slot), so popping a
// child resumes with the next occupied slot without recomputing anything. Children whose
// interval is empty (the ray only touches them) are skipped, which is exactly the kernel's
// "positive length" rule. Fixed axes (direction +-0) have t0 = -inf, t1 = +inf and tm = -inf
// or +inf depending on which side of the mid plane the origin lies (half-open), so they
// select one half and never generate a crossing.
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <span>
#include <utility>

#include "specula/error.h"
#include "specula/svo.h"
#include "voxel/voxel_brute.h"

namespace specula {

namespace {
constexpr auto kPopcount8 = [] {
  std::array<uint8_t, 256> t{};
  for (unsigned i = 0; i < 256; ++i) t[i] = static_cast<uint8_t>(std::popcount(i));
  return t;
}();
}  // namespace

using voxel::CellHit;
using voxel::LocalRay;

class SvoTraversal {
 public:
  /// Visits the leaves (voxels, or nodes at the lod level) the ray crosses, in ray order,
  /// calling leaf(lr, cell, attrs, prim) with the ray in the leaf level's frame and the leaf's
  /// integer cell; stops when it returns true.
  template <bool kStats, class Leaf>
  static void walk(const SparseVoxelOctree& s, const Ray& ray, TraceStats& stats, Leaf&& leaf) {
    if constexpr (kStats) ++stats.rays;
    LocalRay r;
    if (s.leaf_attrs_.empty() || !voxel::make_local_ray(ray, s.grid_, r)) return;
    const int depth = s.grid_.depth;
    if (depth == 0) {
      const uint32_t cell[3] = {0, 0, 0};
      if constexpr (kStats) ++stats.triangles_tested;
      leaf(r, cell, s.leaf_attrs_[0], 0u);
      return;
    }
    const int leaf_level = (s.lod_ > 0 && s.lod_ < depth) ? s.lod_ : depth;
    const int shift = depth - leaf_level;
    const LocalRay rl = shift > 0 ? voxel::coarsen(r, shift) : r;
    const uint32_t res = 1u << depth;
    const uint32_t mirror = r.mirror;
    const uint32_t n_leaves = static_cast<uint32_t>(s.leaf_attrs_.size());
    const SvoNode* nodes = s.nodes_.data();

    struct Frame {
      float t0[3], t1[3], tm[3];
      uint32_t pos[3];
      uint32_t first_child, mask;
      uint32_t todo;  ///< slots still to visit, 4 bits each (slot | 8), nearest first
    };
    Frame stack[kMaxVoxelDepth + 1];
    Frame* f = stack;
    for (int i = 0; i < 3; ++i) {
      f->pos[i] = 0;
      if ((r.fixed >> i) & 1u) {
        if (!(0.0f <= r.o[i] && r.o[i] < static_cast<float>(res))) return;
        f->t0[i] = -kInf;
        f->t1[i] = kInf;
      } else {
        const bool neg = (mirror >> i) & 1u;
        f->t0[i] = ((neg ? static_cast<float>(res) : 0.0f) - r.o[i]) * r.inv[i];
        f->t1[i] = ((neg ? 0.0f : static_cast<float>(res)) - r.o[i]) * r.inv[i];
      }
    }
    f->first_child = nodes[0].first_child;
    f->mask = nodes[0].mask;

    int level = 0;
    uint32_t half = res >> 1;  // side of the current node's children, in voxels
    for (;;) {
      // Entering node f: mid planes, then the slots the ray crosses in order (the first one,
      // then across each mid plane crossed inside the node, nearest first), keeping the
      // occupied ones.
      if constexpr (kStats) ++stats.nodes_visited;
      {
        const float te = std::max(std::max(f->t0[0], f->t0[1]), std::max(f->t0[2], r.tmin));
        const float tx = std::min(std::min(f->t1[0], f->t1[1]), std::min(f->t1[2], r.tmax));
        if (!(te < tx)) goto pop;  // only the root can get here (nodes are entered with te < tx)
        float tm[3];
        for (int i = 0; i < 3; ++i) {
          const float mid = static_cast<float>(f->pos[i] + half);
          tm[i] = ((r.fixed >> i) & 1u) ? (r.o[i] >= mid ? -kInf : kInf) : (mid - r.o[i]) * r.inv[i];
          f->tm[i] = tm[i];
        }
        uint32_t a = (tm[0] <= te ? 1u : 0u) | (tm[1] <= te ? 2u : 0u) | (tm[2] <= te ? 4u : 0u);
        int o0 = 0, o1 = 1, o2 = 2;
        if (tm[o1] < tm[o0]) std::swap(o0, o1);
        if (tm[o2] < tm[o1]) std::swap(o1, o2);
        if (tm[o1] < tm[o0]) std::swap(o0, o1);
        const uint32_t occ = f->mask;
        uint32_t todo = 0, bits = 0;
        const auto add = [&](uint32_t slot) {
          if ((occ >> (slot ^ mirror)) & 1u) {
            todo |= (slot | 8u) << bits;
            bits += 4;
          }
        };
        add(a);
        for (const int o : {o0, o1, o2}) {
          if (!((a >> o) & 1u) && tm[o] < tx) {
            a |= 1u << o;
            add(a);
          }
        }
        f->todo = todo;
      }
      for (;;) {
        while (f->todo == 0) {
        pop:
          if (level == 0) return;
          --f;
          --level;
          half <<= 1;
        }
        const uint32_t a = f->todo & 7u;
        f->todo >>= 4;
        float ct0[3], ct1[3];
        for (int i = 0; i < 3; ++i) {
          const bool far = (a >> i) & 1u;
          ct0[i] = far ? f->tm[i] : f->t0[i];
          ct1[i] = far ? f->t1[i] : f->tm[i];
        }
        const float cte = std::max(std::max(ct0[0], ct0[1]), std::max(ct0[2], r.tmin));
        const float ctx = std::min(std::min(ct1[0], ct1[1]), std::min(ct1[2], r.tmax));
        if (!(cte < ctx)) continue;
        const uint32_t real = a ^ mirror;
        const uint32_t child = f->first_child + kPopcount8[f->mask & ((1u << real) - 1u)];
        uint32_t pos[3];
        for (int i = 0; i < 3; ++i) pos[i] = f->pos[i] + (((real >> i) & 1u) ? half : 0u);
        if (level + 1 == leaf_level) {
          if constexpr (kStats) ++stats.triangles_tested;
          const uint32_t cell[3] = {pos[0] >> shift, pos[1] >> shift, pos[2] >> shift};
          const bool stop = shift == 0 ? leaf(rl, cell, s.leaf_attrs_[child], child)
                                       : leaf(rl, cell, s.inner_attrs_[child], n_leaves + child);
          if (stop) return;
          continue;
        }
        Frame* c = f + 1;
        for (int i = 0; i < 3; ++i) {
          c->t0[i] = ct0[i];
          c->t1[i] = ct1[i];
          c->pos[i] = pos[i];
        }
        const SvoNode node = nodes[child];
        c->first_child = node.first_child;
        c->mask = node.mask;
        f = c;
        ++level;
        half >>= 1;
        break;  // enter the child
      }
    }
  }

  template <bool kStats>
  static Hit closest(const SparseVoxelOctree& s, const Ray& ray, uint32_t skip, TraceStats& stats) {
    Hit hit;
    const VoxelHitMode mode = s.mode_;
    walk<kStats>(s, ray, stats, [&](const LocalRay& r, const uint32_t* cell, const VoxelAttributes& attrs, uint32_t prim) {
      CellHit h;
      if (attrs.material == skip || !voxel::hit_cell(r, cell, attrs, mode, h)) return false;
      hit.t = h.t;
      hit.prim = prim;
      hit.ng = h.n;
      return true;
    });
    return hit;
  }

  template <bool kStats>
  static Vec3 transmit(const SparseVoxelOctree& s, const Ray& ray, TraceStats& stats) {
    Vec3 tr{1.0f, 1.0f, 1.0f};
    const VoxelHitMode mode = s.mode_;
    walk<kStats>(s, ray, stats, [&](const LocalRay& r, const uint32_t* cell, const VoxelAttributes& attrs, uint32_t) {
      CellHit h;
      if (!voxel::hit_cell(r, cell, attrs, mode, h)) return false;
      if (!(attrs.transparency > 0.0f)) {
        tr = Vec3{};
        return true;
      }
      tr *= Vec3(attrs.transparency);
      return false;
    });
    return tr;
  }
};

void SparseVoxelOctree::intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip,
                                           std::span<Hit> hits, TraceStats* stats) const {
  if (hits.size() < rays.size()) throw Error("svo: hits span smaller than rays span");
  if (!skip.empty() && skip.size() < rays.size()) throw Error("svo: skip span smaller than rays span");
  const auto skip_of = [&](size_t i) { return skip.empty() ? kNoHit : skip[i]; };
  if (stats) {
    TraceStats local;
    for (size_t i = 0; i < rays.size(); ++i) hits[i] = SvoTraversal::closest<true>(*this, rays[i], skip_of(i), local);
    *stats += local;
  } else {
    TraceStats unused;
    for (size_t i = 0; i < rays.size(); ++i) hits[i] = SvoTraversal::closest<false>(*this, rays[i], skip_of(i), unused);
  }
}

void SparseVoxelOctree::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("svo: output span smaller than rays span");
  if (stats) {
    TraceStats local;
    for (size_t i = 0; i < rays.size(); ++i) out[i] = SvoTraversal::transmit<true>(*this, rays[i], local);
    *stats += local;
  } else {
    TraceStats unused;
    for (size_t i = 0; i < rays.size(); ++i) out[i] = SvoTraversal::transmit<false>(*this, rays[i], unused);
  }
}

}  // namespace specula
