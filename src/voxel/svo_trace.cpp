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

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

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

/// kSlotMask[mirror][mask]: bit s set when child s ^ mirror exists (the occupied children as
/// slots, i.e. in ray order for rays of that direction octant).
constexpr auto kSlotMask = [] {
  std::array<std::array<uint8_t, 256>, 8> t{};
  for (unsigned m = 0; m < 8; ++m)
    for (unsigned mask = 0; mask < 256; ++mask)
      for (unsigned s = 0; s < 8; ++s)
        if ((mask >> (s ^ m)) & 1u) t[m][mask] = static_cast<uint8_t>(t[m][mask] | (1u << s));
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

/// What the traversals read of an octree.
struct SvoView {
  const SvoNode* nodes;
  const VoxelAttributes* leaf_attrs;
  const VoxelAttributes* inner_attrs;
  uint32_t n_leaves;
  int depth;       ///< grid depth (planes are in voxels of this level)
  int leaf_level;  ///< level whose nodes are the leaves (depth, or the lod level)
  int shift;       ///< depth - leaf_level
  VoxelHitMode mode;

  const VoxelAttributes& attrs(uint32_t child) const { return shift == 0 ? leaf_attrs[child] : inner_attrs[child]; }
  uint32_t prim(uint32_t child) const { return shift == 0 ? child : n_leaves + child; }
};

/// The single-ray traversal of the subtree of node \p node (level \p level, minimum corner
/// \p c in voxels): calls leaf(cell, child) for the leaves the ray crosses in ray order
/// (cell in the leaf level's integer coordinates, child = index of the leaf in its level);
/// returns true as soon as leaf() does.
template <bool kStats, class Leaf>
bool walk_node(const SvoView& v, const LocalRay& r, int level, const int32_t c[3], uint32_t node, TraceStats& stats,
               Leaf&& leaf) {
  const int start_level = level;
  const int32_t res = int32_t{1} << v.depth;
  const uint32_t mirror = r.mirror;
  const SvoNode* nodes = v.nodes;

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

  struct alignas(16) Frame {
    __m128 tm;          ///< mid planes (lane 3: tmax)
    __m128 nf;          ///< far planes along the ray (lane 3: tmax)
    __m128i corner;     ///< minimum corner in voxels (lane 3: 0)
    float nx;           ///< exit distance: min(nf)
    uint32_t first_child, mask;
  };
  Frame stack[kMaxVoxelDepth + 1];
  Frame* f = stack;

  // The start node: near planes at its minimum corner (maximum on mirrored axes), far planes
  // opposite.
  const __m128i corner = _mm_setr_epi32(c[0], c[1], c[2], 0);
  const __m128i side = _mm_and_si128(_mm_set1_epi32(res >> level), xyz);
  alignas(16) float near[4];
  _mm_store_ps(near, plane_t(_mm_add_epi32(corner, _mm_and_si128(mirror_lanes, side))));
  float t = std::max(std::max(near[0], near[1]), std::max(near[2], r.tmin));
  f->nf = plane_t(_mm_add_epi32(corner, _mm_andnot_si128(mirror_lanes, side)));
  f->nx = hmin(f->nf);
  if (!(t < f->nx)) return false;
  f->corner = corner;
  int32_t half = (res >> level) >> 1;  // side of the current node's children, in voxels
  f->tm = plane_t(_mm_add_epi32(corner, _mm_and_si128(_mm_set1_epi32(half), xyz)));
  f->first_child = nodes[node].first_child;
  f->mask = nodes[node].mask;
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
      const __m128i cc = _mm_add_epi32(f->corner, _mm_and_si128(slot_lanes(real), _mm_set1_epi32(half)));
      if (level + 1 == v.leaf_level) {
        if constexpr (kStats) ++stats.triangles_tested;
        alignas(16) uint32_t cell[4];
        _mm_store_si128(reinterpret_cast<__m128i*>(cell), _mm_srli_epi32(cc, v.shift));
        if (leaf(static_cast<const uint32_t*>(cell), child)) return true;
      } else {
        // Enter the child at the same t.
        Frame* ch = f + 1;
        ch->corner = cc;
        ch->nf = cf;
        ch->nx = tx;
        half >>= 1;
        ch->tm = plane_t(_mm_add_epi32(cc, _mm_and_si128(_mm_set1_epi32(half), xyz)));
        const SvoNode n = nodes[child];
        ch->first_child = n.first_child;
        ch->mask = n.mask;
        f = ch;
        ++level;
        if constexpr (kStats) ++stats.nodes_visited;
        continue;
      }
    }
    // Step over the child; leave the nodes whose exit is reached.
    t = tx;
    while (!(t < f->nx)) {
      if (level == start_level) return false;
      --f;
      --level;
      half <<= 1;
    }
  }
}

/// The widest packet: two AVX-512 vectors.
constexpr int kMaxPacket = 32;

/// Up to kMaxPacket rays of one direction octant (same mirror) in structure-of-arrays form, in
/// the grid's local frame; fixed axes have inv = +inf (see the file comment).
struct alignas(64) PacketRays {
  float o[3][kMaxPacket];
  float inv[3][kMaxPacket];
  float d[3][kMaxPacket];  ///< direction, 0 on fixed axes (as LocalRay::d; for the contour test)
  float tmin[kMaxPacket];
  float tmax[kMaxPacket];
  float scale;             ///< LocalRay::scale, the same for every ray of a batch
};

/// 32 lanes as two AVX-512 vectors, for the widest packets: the operations the packet kernel
/// uses, lane by lane, with lane masks of 32 bits (bits 16-31 from the second vector).
struct alignas(64) V32 {
  __m512 lo, hi;
};
#define SPECULA_V32 __attribute__((target("avx2,avx512f,popcnt,bmi"), always_inline)) inline
SPECULA_V32 V32 v32_load(const float* p) { return {_mm512_load_ps(p), _mm512_load_ps(p + 16)}; }
SPECULA_V32 void v32_store(float* p, V32 a) {
  _mm512_store_ps(p, a.lo);
  _mm512_store_ps(p + 16, a.hi);
}
SPECULA_V32 V32 v32_set1(float x) { return {_mm512_set1_ps(x), _mm512_set1_ps(x)}; }
SPECULA_V32 V32 v32_add(V32 a, V32 b) { return {_mm512_add_ps(a.lo, b.lo), _mm512_add_ps(a.hi, b.hi)}; }
SPECULA_V32 V32 v32_sub(V32 a, V32 b) { return {_mm512_sub_ps(a.lo, b.lo), _mm512_sub_ps(a.hi, b.hi)}; }
SPECULA_V32 V32 v32_mul(V32 a, V32 b) { return {_mm512_mul_ps(a.lo, b.lo), _mm512_mul_ps(a.hi, b.hi)}; }
SPECULA_V32 V32 v32_div(V32 a, V32 b) { return {_mm512_div_ps(a.lo, b.lo), _mm512_div_ps(a.hi, b.hi)}; }
// Zero-masking forms with every lane set, as for 16 lanes (see SVO_MIN below).
SPECULA_V32 V32 v32_min(V32 a, V32 b) {
  return {_mm512_maskz_min_ps(0xFFFF, a.lo, b.lo), _mm512_maskz_min_ps(0xFFFF, a.hi, b.hi)};
}
SPECULA_V32 V32 v32_max(V32 a, V32 b) {
  return {_mm512_maskz_max_ps(0xFFFF, a.lo, b.lo), _mm512_maskz_max_ps(0xFFFF, a.hi, b.hi)};
}
template <int kCmp>
SPECULA_V32 uint32_t v32_cmp(V32 a, V32 b) {
  return static_cast<uint32_t>(_mm512_cmp_ps_mask(a.lo, b.lo, kCmp)) |
         static_cast<uint32_t>(_mm512_cmp_ps_mask(a.hi, b.hi, kCmp)) << 16;
}
/// Per lane a >= b ? x : y (ordered).
SPECULA_V32 V32 v32_sel_ge(V32 a, V32 b, V32 x, V32 y) {
  return {_mm512_mask_blend_ps(_mm512_cmp_ps_mask(a.lo, b.lo, _CMP_GE_OQ), y.lo, x.lo),
          _mm512_mask_blend_ps(_mm512_cmp_ps_mask(a.hi, b.hi, _CMP_GE_OQ), y.hi, x.hi)};
}
#undef SPECULA_V32

/// 16 lanes as two AVX2 vectors (the widest packets without AVX-512), masks of 16 bits. (V32's
/// twin rather than one template over both: its functions would need one target attribute for
/// both instruction sets, and the AVX2 kernel cannot inline functions that may use AVX-512.)
struct alignas(32) V16 {
  __m256 lo, hi;
};
#define SPECULA_V16 __attribute__((target("avx2,popcnt,bmi"), always_inline)) inline
SPECULA_V16 V16 v16_load(const float* p) { return {_mm256_load_ps(p), _mm256_load_ps(p + 8)}; }
SPECULA_V16 void v16_store(float* p, V16 a) {
  _mm256_store_ps(p, a.lo);
  _mm256_store_ps(p + 8, a.hi);
}
SPECULA_V16 V16 v16_set1(float x) { return {_mm256_set1_ps(x), _mm256_set1_ps(x)}; }
SPECULA_V16 V16 v16_add(V16 a, V16 b) { return {_mm256_add_ps(a.lo, b.lo), _mm256_add_ps(a.hi, b.hi)}; }
SPECULA_V16 V16 v16_sub(V16 a, V16 b) { return {_mm256_sub_ps(a.lo, b.lo), _mm256_sub_ps(a.hi, b.hi)}; }
SPECULA_V16 V16 v16_mul(V16 a, V16 b) { return {_mm256_mul_ps(a.lo, b.lo), _mm256_mul_ps(a.hi, b.hi)}; }
SPECULA_V16 V16 v16_div(V16 a, V16 b) { return {_mm256_div_ps(a.lo, b.lo), _mm256_div_ps(a.hi, b.hi)}; }
SPECULA_V16 V16 v16_min(V16 a, V16 b) { return {_mm256_min_ps(a.lo, b.lo), _mm256_min_ps(a.hi, b.hi)}; }
SPECULA_V16 V16 v16_max(V16 a, V16 b) { return {_mm256_max_ps(a.lo, b.lo), _mm256_max_ps(a.hi, b.hi)}; }
template <int kCmp>
SPECULA_V16 uint32_t v16_cmp(V16 a, V16 b) {
  return static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(a.lo, b.lo, kCmp))) |
         static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(a.hi, b.hi, kCmp))) << 8;
}
/// Per lane a >= b ? x : y (ordered).
SPECULA_V16 V16 v16_sel_ge(V16 a, V16 b, V16 x, V16 y) {
  return {_mm256_blendv_ps(y.lo, x.lo, _mm256_cmp_ps(a.lo, b.lo, _CMP_GE_OQ)),
          _mm256_blendv_ps(y.hi, x.hi, _mm256_cmp_ps(a.hi, b.hi, _CMP_GE_OQ))};
}
#undef SPECULA_V16

}  // namespace specula

// The packet kernels: one source, compiled per vector width and instruction set: 8 lanes
// (AVX2), 16 (AVX2 as two vectors, V16 above: the default there), 16 (AVX-512) and 32 (AVX-512
// as two vectors, V32: the default there). The one-vector kernels are kept for the tests and
// for comparison.
#define SVO_NS svo_avx2
#define SVO_TARGET __attribute__((target("avx2,popcnt,bmi")))
#define SVO_WIDTH 8
#define SVO_VF __m256
#define SVO_LOAD _mm256_load_ps
#define SVO_SET1 _mm256_set1_ps
#define SVO_SUB _mm256_sub_ps
#define SVO_MUL _mm256_mul_ps
#define SVO_MIN _mm256_min_ps
#define SVO_MAX _mm256_max_ps
#define SVO_LT(a, b) static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps((a), (b), _CMP_LT_OQ)))
#define SVO_GE(a, b) static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps((a), (b), _CMP_GE_OQ)))
#define SVO_SEL_GE(a, b, x, y) _mm256_blendv_ps((y), (x), _mm256_cmp_ps((a), (b), _CMP_GE_OQ))
#define SVO_STORE _mm256_store_ps
#define SVO_ADD _mm256_add_ps
#define SVO_DIV _mm256_div_ps
#define SVO_LE(a, b) static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps((a), (b), _CMP_LE_OQ)))
#define SVO_EQ(a, b) static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps((a), (b), _CMP_EQ_OQ)))
#include "voxel/svo_packet.inc"  // (undefines the SVO_ macros at its end)

#define SVO_NS svo_avx2x2
#define SVO_TARGET __attribute__((target("avx2,popcnt,bmi")))
#define SVO_WIDTH 16
#define SVO_VF V16
#define SVO_LOAD v16_load
#define SVO_SET1 v16_set1
#define SVO_SUB v16_sub
#define SVO_MUL v16_mul
#define SVO_MIN v16_min
#define SVO_MAX v16_max
#define SVO_LT(a, b) v16_cmp<_CMP_LT_OQ>((a), (b))
#define SVO_GE(a, b) v16_cmp<_CMP_GE_OQ>((a), (b))
#define SVO_SEL_GE(a, b, x, y) v16_sel_ge((a), (b), (x), (y))
#define SVO_STORE v16_store
#define SVO_ADD v16_add
#define SVO_DIV v16_div
#define SVO_LE(a, b) v16_cmp<_CMP_LE_OQ>((a), (b))
#define SVO_EQ(a, b) v16_cmp<_CMP_EQ_OQ>((a), (b))
#include "voxel/svo_packet.inc"  // (undefines the SVO_ macros at its end)

#define SVO_NS svo_avx512
#define SVO_TARGET __attribute__((target("avx2,avx512f,popcnt,bmi")))
#define SVO_WIDTH 16
#define SVO_VF __m512
#define SVO_LOAD _mm512_load_ps
#define SVO_SET1 _mm512_set1_ps
#define SVO_SUB _mm512_sub_ps
#define SVO_MUL _mm512_mul_ps
// Full-mask zero-masking max / min: GCC 12's plain _mm512_max_ps merges into an undefined
// register and trips -Wmaybe-uninitialized; with every lane set the result is the same.
#define SVO_MIN(a, b) _mm512_maskz_min_ps(0xFFFF, (a), (b))
#define SVO_MAX(a, b) _mm512_maskz_max_ps(0xFFFF, (a), (b))
#define SVO_LT(a, b) static_cast<uint32_t>(_mm512_cmp_ps_mask((a), (b), _CMP_LT_OQ))
#define SVO_GE(a, b) static_cast<uint32_t>(_mm512_cmp_ps_mask((a), (b), _CMP_GE_OQ))
#define SVO_SEL_GE(a, b, x, y) _mm512_mask_blend_ps(_mm512_cmp_ps_mask((a), (b), _CMP_GE_OQ), (y), (x))
#define SVO_STORE _mm512_store_ps
#define SVO_ADD _mm512_add_ps
#define SVO_DIV _mm512_div_ps
#define SVO_LE(a, b) static_cast<uint32_t>(_mm512_cmp_ps_mask((a), (b), _CMP_LE_OQ))
#define SVO_EQ(a, b) static_cast<uint32_t>(_mm512_cmp_ps_mask((a), (b), _CMP_EQ_OQ))
#include "voxel/svo_packet.inc"  // (undefines the SVO_ macros at its end)

#define SVO_NS svo_avx512x2
#define SVO_TARGET __attribute__((target("avx2,avx512f,popcnt,bmi")))
#define SVO_WIDTH 32
#define SVO_VF V32
#define SVO_LOAD v32_load
#define SVO_SET1 v32_set1
#define SVO_SUB v32_sub
#define SVO_MUL v32_mul
#define SVO_MIN v32_min
#define SVO_MAX v32_max
#define SVO_LT(a, b) v32_cmp<_CMP_LT_OQ>((a), (b))
#define SVO_GE(a, b) v32_cmp<_CMP_GE_OQ>((a), (b))
#define SVO_SEL_GE(a, b, x, y) v32_sel_ge((a), (b), (x), (y))
#define SVO_STORE v32_store
#define SVO_ADD v32_add
#define SVO_DIV v32_div
#define SVO_LE(a, b) v32_cmp<_CMP_LE_OQ>((a), (b))
#define SVO_EQ(a, b) v32_cmp<_CMP_EQ_OQ>((a), (b))
#include "voxel/svo_packet.inc"  // (undefines the SVO_ macros at its end)

namespace specula {

namespace voxel {
namespace {
std::atomic<int> g_packet_width_limit{kMaxPacket};
std::atomic<bool> g_packet_avx512{true};

/// 0: no packets; 1: AVX2; 2: AVX2 and AVX-512F.
int cpu_packet_isa() {
  static const int isa = [] {
    if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("popcnt") || !__builtin_cpu_supports("bmi")) return 0;
    return __builtin_cpu_supports("avx512f") ? 2 : 1;
  }();
  return isa;
}
}  // namespace

SvoPacketKernel svo_packet_kernel() {
  // The widest kernel within the CPU's instruction sets and the limits: AVX-512 32 lanes (two
  // vectors) or 16; AVX2 16 lanes (two vectors) or 8; else single rays.
  const int isa = std::min(cpu_packet_isa(), g_packet_avx512.load(std::memory_order_relaxed) ? 2 : 1);
  const int limit = g_packet_width_limit.load(std::memory_order_relaxed);
  if (isa == 0 || limit < 8) return {1, false};
  if (isa == 2 && limit >= 16) return {limit >= 32 ? 32 : 16, true};
  return {limit >= 16 ? 16 : 8, false};
}
void set_svo_packet_width_limit(int width, bool avx512) {
  g_packet_width_limit.store(std::max(width, 1), std::memory_order_relaxed);
  g_packet_avx512.store(avx512, std::memory_order_relaxed);
}
}  // namespace voxel

class SvoTraversal {
 public:
  static SvoView view(const SparseVoxelOctree& s) {
    const int depth = s.grid_.depth;
    const int leaf_level = (s.lod_ > 0 && s.lod_ < depth) ? s.lod_ : depth;
    return SvoView{s.nodes_.data(), s.leaf_attrs_.data(), s.inner_attrs_.data(),
                   static_cast<uint32_t>(s.leaf_attrs_.size()), depth, leaf_level, depth - leaf_level, s.mode_};
  }

  /// One ray: calls leaf(lr, cell, attrs, prim, nullptr) for the leaves (voxels, or nodes at
  /// the lod level) it crosses, in ray order, with the ray in the leaf level's frame; stops when
  /// leaf returns true.
  template <bool kStats, class Leaf>
  static void walk(const SparseVoxelOctree& s, const Ray& ray, TraceStats& stats, Leaf&& leaf) {
    if constexpr (kStats) ++stats.rays;
    LocalRay r;
    if (s.leaf_attrs_.empty() || !voxel::make_local_ray(ray, s.grid_, r)) return;
    if (s.grid_.depth == 0) {
      const uint32_t cell[3] = {0, 0, 0};
      if constexpr (kStats) ++stats.triangles_tested;
      leaf(r, cell, s.leaf_attrs_[0], 0u, nullptr);
      return;
    }
    const SvoView v = view(s);
    const LocalRay rl = v.shift > 0 ? voxel::coarsen(r, v.shift) : r;
    const int32_t root[3] = {0, 0, 0};
    walk_node<kStats>(v, r, 0, root, 0, stats,
                      [&](const uint32_t* cell, uint32_t child) {
                        return leaf(rl, cell, v.attrs(child), v.prim(child), nullptr);
                      });
  }

  /// A batch: rays are mapped to the local frame, grouped by direction octant (keeping their
  /// order, so neighbours in the batch stay neighbours) and traced in packets of the CPU's
  /// vector width; a lone ray (or a CPU without AVX2) uses the single-ray traversal.
  /// lane_leaf(i, lr, cell, attrs, prim, span) is called for ray i (index into the batch) and
  /// returns true when the ray is done; span is null or what the packet computed of the ray's
  /// crossing of the cell (voxel::CellCrossing; without the level of detail).
  template <bool kStats, class LaneLeaf>
  static void batch(const SparseVoxelOctree& s, std::span<const Ray> rays, TraceStats& stats, LaneLeaf&& lane_leaf) {
    if constexpr (kStats) stats.rays += rays.size();
    if (s.leaf_attrs_.empty() || rays.empty()) return;
    const SvoView v = view(s);
    struct Scratch {
      std::vector<LocalRay> local;
      std::vector<uint32_t> order;
    };
    thread_local Scratch scratch;
    std::vector<LocalRay>& local = scratch.local;
    std::vector<uint32_t>& order = scratch.order;
    local.resize(rays.size());
    order.resize(rays.size());
    uint32_t count[9] = {};
    const voxel::LocalFrame frame(s.grid_);
    // Through plain pointers from here on: stores into the rays (or anything else) would
    // otherwise make GCC reload the thread-local vectors' data pointers for every ray.
    LocalRay* const lr = local.data();
    uint32_t* const ord = order.data();
    {
      const Ray* const in = rays.data();
      const size_t nr = rays.size();
      for (size_t i = 0; i < nr; ++i) {
        LocalRay& r = lr[i];
        if (!voxel::make_local_ray(in[i], frame, r)) r.mirror = 8;  // misses by definition
        ++count[r.mirror];
      }
    }
    uint32_t start[9];
    uint32_t sum = 0;
    for (int k = 0; k < 9; ++k) {
      start[k] = sum;
      sum += count[k];
    }
    if (count[lr[0].mirror] == rays.size()) {
      // One octant (the usual case for a tile's primary rays): the order is the batch's own,
      // without the counting sort's chain of read-modify-writes on start[].
      for (size_t i = 0; i < rays.size(); ++i) ord[i] = static_cast<uint32_t>(i);
      start[lr[0].mirror] += static_cast<uint32_t>(rays.size());
    } else {
      for (size_t i = 0; i < rays.size(); ++i) ord[start[lr[i].mirror]++] = static_cast<uint32_t>(i);
    }
    const uint32_t valid = start[7];  // after the loop start[k] is the end of octant k

    const voxel::SvoPacketKernel kernel = voxel::svo_packet_kernel();
    const int width = s.grid_.depth == 0 ? 1 : kernel.width;
    const int32_t root[3] = {0, 0, 0};
    const auto single = [&](uint32_t i) {
      const LocalRay& r = lr[i];
      if (s.grid_.depth == 0) {
        const uint32_t cell[3] = {0, 0, 0};
        if constexpr (kStats) ++stats.triangles_tested;
        lane_leaf(i, r, cell, s.leaf_attrs_[0], 0u, nullptr);
        return;
      }
      const LocalRay rl = v.shift > 0 ? voxel::coarsen(r, v.shift) : r;
      walk_node<kStats>(v, r, 0, root, 0, stats, [&](const uint32_t* cell, uint32_t child) {
        return lane_leaf(i, rl, cell, v.attrs(child), v.prim(child), nullptr);
      });
    };
    if (width <= 1) {
      for (uint32_t k = 0; k < valid; ++k) single(ord[k]);
      return;
    }
    PacketRays p;
    p.scale = frame.scale;
    const int spans = v.shift != 0 ? 0 : v.mode == VoxelHitMode::Contours ? 2 : 1;
    LocalRay coarse[kMaxPacket];     // the lanes' rays in the lod level's frame (shift > 0 only)
    const LocalRay* rl[kMaxPacket];  // each lane's ray for the leaf tests
    uint32_t idx[kMaxPacket];
    for (uint32_t begin = 0, octant_end = 0; begin < valid; begin = std::min(begin + static_cast<uint32_t>(width), octant_end)) {
      // Packets never straddle two octants.
      const uint32_t mirror = lr[ord[begin]].mirror;
      octant_end = start[mirror];
      const uint32_t n = std::min(static_cast<uint32_t>(width), octant_end - begin);
      if (n == 1) {
        single(ord[begin]);
        continue;
      }
      uint32_t fixed = 0;  // some lane does not move along some axis
      for (int j = 0; j < width; ++j) {
        const uint32_t i = ord[begin + std::min(static_cast<uint32_t>(j), n - 1)];
        const LocalRay& r = lr[i];
        idx[j] = i;
        fixed |= r.fixed;
        for (int a = 0; a < 3; ++a) {
          p.o[a][j] = r.o[a];
          p.inv[a][j] = ((r.fixed >> a) & 1u) ? kInf : r.inv[a];
        }
        p.tmin[j] = r.tmin;
        p.tmax[j] = r.tmax;
        if (j < static_cast<int>(n)) {
          if (v.shift > 0) {
            coarse[j] = voxel::coarsen(r, v.shift);
            rl[j] = &coarse[j];
          } else {
            rl[j] = &r;
          }
        }
      }
      if (spans == 2)  // the contour test's directions
        for (int j = 0; j < width; ++j)
          for (int a = 0; a < 3; ++a) p.d[a][j] = lr[idx[j]].d[a];
      const uint32_t lanes = n >= 32 ? ~0u : (1u << n) - 1u;
      const auto leaf = [&](int j, const uint32_t* cell, uint32_t child, const voxel::CellCrossing* span) {
        return lane_leaf(idx[j], *rl[j], cell, v.attrs(child), v.prim(child), span);
      };
      const auto scalar = [&](int j, int level, const int32_t* c, uint32_t node) {
        return walk_node<kStats>(v, lr[idx[j]], level, c, node, stats, [&](const uint32_t* cell, uint32_t child) {
          return leaf(j, cell, child, nullptr);
        });
      };
      // Spans from the packet's planes when the leaves are voxels, and in contour mode the slab
      // test too (see packet_walk): kSpan 0 none, 1 spans, 2 spans and contours.
      const auto run = [&]<bool kFixed, int kSpan>() {
        if (width == 32) svo_avx512x2::packet_walk<kStats, kFixed, kSpan>(v, p, mirror, lanes, stats, leaf, scalar);
        else if (width == 16 && kernel.avx512) svo_avx512::packet_walk<kStats, kFixed, kSpan>(v, p, mirror, lanes, stats, leaf, scalar);
        else if (width == 16) svo_avx2x2::packet_walk<kStats, kFixed, kSpan>(v, p, mirror, lanes, stats, leaf, scalar);
        else svo_avx2::packet_walk<kStats, kFixed, kSpan>(v, p, mirror, lanes, stats, leaf, scalar);
      };
      if (fixed) {
        if (spans == 0) run.template operator()<true, 0>();
        else if (spans == 1) run.template operator()<true, 1>();
        else run.template operator()<true, 2>();
      } else {
        if (spans == 0) run.template operator()<false, 0>();
        else if (spans == 1) run.template operator()<false, 1>();
        else run.template operator()<false, 2>();
      }
    }
  }

  template <bool kStats>
  static void closest(const SparseVoxelOctree& s, std::span<const Ray> rays, std::span<const uint32_t> skip,
                      std::span<const uint32_t> skip_prim, std::span<Hit> hits, TraceStats& stats) {
    for (size_t i = 0; i < rays.size(); ++i) hits[i] = Hit{};
    const VoxelHitMode mode = s.mode_;
    // Plain pointers, captured by value (null: nothing to skip).
    const uint32_t* const skip_m = skip.empty() ? nullptr : skip.data();
    const uint32_t* const skip_p = skip_prim.empty() ? nullptr : skip_prim.data();
    Hit* const out = hits.data();
    batch<kStats>(s, rays, stats, [mode, skip_m, skip_p, out](uint32_t i, const LocalRay& r, const uint32_t* cell,
                                                              const VoxelAttributes& attrs, uint32_t prim,
                                                              const voxel::CellCrossing* span) {
      CellHit h;
      if ((skip_m && attrs.material == skip_m[i]) || (skip_p && prim == skip_p[i]) ||
          !(span ? voxel::hit_crossing(r, cell, attrs, mode, *span, h) : voxel::hit_cell(r, cell, attrs, mode, h)))
        return false;
      Hit& hit = out[i];
      hit.t = h.t;
      hit.prim = prim;
      hit.ng = h.n;
      return true;
    });
  }

  template <bool kStats>
  static void transmit(const SparseVoxelOctree& s, std::span<const Ray> rays, std::span<Vec3> out, TraceStats& stats) {
    for (size_t i = 0; i < rays.size(); ++i) out[i] = Vec3{1.0f, 1.0f, 1.0f};
    const VoxelHitMode mode = s.mode_;
    Vec3* const tr = out.data();
    batch<kStats>(s, rays, stats, [mode, tr](uint32_t i, const LocalRay& r, const uint32_t* cell,
                                             const VoxelAttributes& attrs, uint32_t, const voxel::CellCrossing* span) {
      // Both traversals only report leaves the ray crosses with positive length (the kernel's
      // own test), so in cube mode every reported voxel is hit.
      CellHit h;
      if (mode != VoxelHitMode::Cubes &&
          !(span ? voxel::hit_crossing(r, cell, attrs, mode, *span, h) : voxel::hit_cell(r, cell, attrs, mode, h)))
        return false;
      if (!(attrs.transparency > 0.0f)) {
        tr[i] = Vec3{};
        return true;
      }
      tr[i] *= Vec3(attrs.transparency);
      return false;
    });
  }
};

void SparseVoxelOctree::intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip,
                                           std::span<Hit> hits, TraceStats* stats,
                                           std::span<const uint32_t> skip_prim) const {
  if (hits.size() < rays.size()) throw Error("svo: hits span smaller than rays span");
  if (!skip.empty() && skip.size() < rays.size()) throw Error("svo: skip span smaller than rays span");
  if (!skip_prim.empty() && skip_prim.size() < rays.size()) throw Error("svo: skip_prim span smaller than rays span");
  TraceStats local;
  if (stats) {
    SvoTraversal::closest<true>(*this, rays, skip, skip_prim, hits, local);
    *stats += local;
  } else {
    SvoTraversal::closest<false>(*this, rays, skip, skip_prim, hits, local);
  }
}

void SparseVoxelOctree::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("svo: output span smaller than rays span");
  TraceStats local;
  if (stats) {
    SvoTraversal::transmit<true>(*this, rays, out, local);
    *stats += local;
  } else {
    SvoTraversal::transmit<false>(*this, rays, out, local);
  }
}

}  // namespace specula
