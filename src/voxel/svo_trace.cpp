// Sparse voxel octree traversal: closest hit and transmittance (owner: voxel tracers).
//
// Revelles et al.'s parametric traversal as seed 000 extends it, driven by one running
// parameter t instead of per-node child lists. Every node keeps the distances of its three
// mid planes (tm) and of its three far planes (nf), all computed as (integer plane - o) *
// (1 / d) in the grid's local frame, exactly as the shared kernel (voxel_brute.h) computes
// voxel boundaries, so the nodes visited and the hits found are bit-identical to the grid's
// and the brute force's. At time t the ray is in the child whose slot (in ray order, bit i
// set = the far half of axis i along the ray) has bit i set exactly when tm[i] <= t; `slot ^
// mirror` is the real child index (seed 000's mirroring). That child's far planes are nf[i]
// on its far axes and tm[i] on the others, so its exit time tx is one select and one
// horizontal minimum. An occupied child is entered (or, at the leaf level, tested with the
// kernel); an empty one, or a leaf that was not hit, is stepped over by setting t = tx, and
// nodes whose exit time is reached are popped. The child selected at t always has t < tx,
// and t is exactly its entry distance, so every voxel the kernel says is crossed (positive
// length) is visited, in ray order, and no other. Fixed axes (direction +-0) use 1/d = +inf
// here: a plane at or behind the origin gives -inf (0 * inf = NaN is mapped to -inf), one
// ahead of it +inf, which is the kernel's half-open rule. The fourth lane carries tmax (the
// plane vector's lane 3 is 0 and o's is -tmax), so the exit minimum includes it for free.
// One stack frame per level (depth <= 21); SSE2 only (the x86-64 baseline).
#include <immintrin.h>

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

/// Lane i all ones when bit i of the index is set (lane 3 always zero).
alignas(16) constexpr uint32_t kSlotLanes[8][4] = {
    {0, 0, 0, 0}, {~0u, 0, 0, 0}, {0, ~0u, 0, 0}, {~0u, ~0u, 0, 0},
    {0, 0, ~0u, 0}, {~0u, 0, ~0u, 0}, {0, ~0u, ~0u, 0}, {~0u, ~0u, ~0u, 0},
};

inline __m128i slot_lanes(uint32_t slot) {
  return _mm_load_si128(reinterpret_cast<const __m128i*>(kSlotLanes[slot]));
}

inline float hmin(__m128 v) {
  const __m128 m = _mm_min_ps(v, _mm_shuffle_ps(v, v, _MM_SHUFFLE(2, 3, 0, 1)));
  return _mm_cvtss_f32(_mm_min_ps(m, _mm_movehl_ps(m, m)));
}
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
    const int32_t res = int32_t{1} << depth;
    const uint32_t mirror = r.mirror;
    const uint32_t n_leaves = static_cast<uint32_t>(s.leaf_attrs_.size());
    const SvoNode* nodes = s.nodes_.data();

    const auto inv_of = [&r](int i) { return ((r.fixed >> i) & 1u) ? kInf : r.inv[i]; };
    const __m128 o = _mm_setr_ps(r.o[0], r.o[1], r.o[2], -r.tmax);
    const __m128 inv = _mm_setr_ps(inv_of(0), inv_of(1), inv_of(2), 1.0f);
    const __m128 neg_inf = _mm_set1_ps(-kInf);
    // Distances of the integer planes p (lanes 0-2; lane 3 must be 0 and gives tmax).
    const auto plane_t = [&](__m128i p) {
      return _mm_max_ps(_mm_mul_ps(_mm_sub_ps(_mm_cvtepi32_ps(p), o), inv), neg_inf);
    };
    const __m128i mirror_lanes = slot_lanes(mirror);
    const __m128i xyz = slot_lanes(7u);
    const __m128i res_lanes = _mm_setr_epi32(res, res, res, 0);

    struct alignas(16) Frame {
      __m128 tm;          ///< mid planes (lane 3: tmax)
      __m128 nf;          ///< far planes along the ray (lane 3: tmax)
      __m128i corner;     ///< minimum corner in voxels (lane 3: 0)
      float nx;           ///< exit distance: min(nf)
      uint32_t first_child, mask;
    };
    Frame stack[kMaxVoxelDepth + 1];
    Frame* f = stack;

    // Root: near planes at 0 (res on mirrored axes), far planes at res (0 on mirrored axes).
    const __m128i root_near = _mm_and_si128(mirror_lanes, res_lanes);
    const __m128i root_far = _mm_andnot_si128(mirror_lanes, res_lanes);
    alignas(16) float near[4];
    _mm_store_ps(near, plane_t(root_near));
    float t = std::max(std::max(near[0], near[1]), std::max(near[2], r.tmin));
    f->nf = plane_t(root_far);
    f->nx = hmin(f->nf);
    if (!(t < f->nx)) return;
    f->corner = _mm_setzero_si128();
    int level = 0;
    int32_t half = res >> 1;  // side of the current node's children, in voxels
    f->tm = plane_t(_mm_and_si128(_mm_set1_epi32(half), xyz));
    f->first_child = nodes[0].first_child;
    f->mask = nodes[0].mask;
    if constexpr (kStats) ++stats.nodes_visited;

    for (;;) {
      // The child the ray is in at t, and when it leaves it.
      const __m128 le = _mm_cmple_ps(f->tm, _mm_set1_ps(t));
      const uint32_t slot = static_cast<uint32_t>(_mm_movemask_ps(le)) & 7u;
      const __m128 cf = _mm_or_ps(_mm_and_ps(le, f->nf), _mm_andnot_ps(le, f->tm));
      const float tx = hmin(cf);
      const uint32_t real = slot ^ mirror;
      if ((f->mask >> real) & 1u) {
        const uint32_t child = f->first_child + kPopcount8[f->mask & ((1u << real) - 1u)];
        const __m128i corner = _mm_add_epi32(f->corner, _mm_and_si128(slot_lanes(real), _mm_set1_epi32(half)));
        if (level + 1 == leaf_level) {
          if constexpr (kStats) ++stats.triangles_tested;
          alignas(16) uint32_t c[4];
          _mm_store_si128(reinterpret_cast<__m128i*>(c), _mm_srli_epi32(corner, shift));
          const bool stop = shift == 0 ? leaf(rl, c, s.leaf_attrs_[child], child)
                                       : leaf(rl, c, s.inner_attrs_[child], n_leaves + child);
          if (stop) return;
        } else {
          // Enter the child at the same t.
          Frame* ch = f + 1;
          ch->corner = corner;
          ch->nf = cf;
          ch->nx = tx;
          half >>= 1;
          ch->tm = plane_t(_mm_add_epi32(corner, _mm_and_si128(_mm_set1_epi32(half), xyz)));
          const SvoNode node = nodes[child];
          ch->first_child = node.first_child;
          ch->mask = node.mask;
          f = ch;
          ++level;
          if constexpr (kStats) ++stats.nodes_visited;
          continue;
        }
      }
      // Step over the child; leave the nodes whose exit is reached.
      t = tx;
      while (!(t < f->nx)) {
        if (level == 0) return;
        --f;
        --level;
        half <<= 1;
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
