// Binned-SAH BVH construction (owner: accel).
//
// Algorithm: top-down binned SAH as in Wald 2007, "On fast Construction of SAH-based Bounding
// Volume Hierarchies", and Bikker's lecture (seed 004). Every node bins its primitives' centroids
// into equal intervals of the centroid bounds on each axis (4 + n / 20 of them for n primitives,
// at most BvhOptions::bins; see BinParams), sweeps the bins to
// evaluate SAH costs of the bins - 1 candidate planes per axis, and splits at the cheapest plane
// unless making a leaf is cheaper (SAH termination) and the node holds at most max_leaf_size
// triangles. Primitive references (bounds + index, 32 bytes) are partitioned in place, so every
// pass over a node's primitives is a linear walk through memory. Child bounds come for free from
// the winning bin sweep; child centroid bounds are accumulated during the partition.
// The SAH charges leaves per block of four triangles (the traversal tests a BvhTriangle4 block
// at the price of about one triangle), so nodes of up to four triangles become leaves at once.
//
// On CPUs with AVX2 (checked at run time; the library is built for the x86-64 baseline) the
// binning, the SAH sweeps and the partition run in AVX2 variants: a bin is one 256-bit
// (lo, -hi) box grown by a single min, the three axes are swept at once, and a primitive
// reference moves as one 32-byte load/store. They compute exactly the same floats as the SSE2
// path, so the tree does not depend on the CPU either.
//
// Subtrees above a size threshold are built as TBB tasks; node pairs are allocated with an
// atomic counter and renumbered depth-first afterwards, so the result (nodes, triangle order)
// is identical for any thread count. The top nodes, which no other task overlaps, bin their
// primitives on all threads (AVX2 path, nodes of at least kParallelBinMin primitives) in fixed
// chunks whose bins are merged exactly.
#include <emmintrin.h>  // SSE2: part of the x86-64 baseline, no -march needed
#include <immintrin.h>  // AVX2 paths: compiled per function (target attribute), chosen at run time

#include <algorithm>
#include <atomic>
#include <bit>
#include <functional>
#include <string>
#include <type_traits>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include "accel/bvh_optimize.h"
#include "accel/triangles.h"
#include "accel/watertight.h"
#include "core/memory.h"
#include "specula/bvh.h"
#include "specula/error.h"
#include "specula/timer.h"

namespace specula {

namespace {

/// A primitive reference: triangle bounds; lo[3] holds the triangle index (as bits).
/// Twice the centroid is lo + hi (we bin 2c to save a multiply; only ratios matter).
struct alignas(32) PrimRef {
  float lo[4];
  float hi[4];

  uint32_t id() const {
    uint32_t i;
    static_assert(sizeof(i) == sizeof(lo[3]));
    __builtin_memcpy(&i, &lo[3], sizeof(i));
    return i;
  }
};

/// Lane 3 of PrimRef::lo holds the triangle index bits, which read as a float are a denormal
/// (or zero). Floating-point arithmetic with denormal operands takes a slow microcode path on
/// some CPUs (on this project's Zen 5 machine the split search ran at half speed), so every
/// sum, difference or product over a reference uses these masked copies, whose lane 3 is +0.
/// Lanes 0-2 are untouched, so the tree is the same bit for bit.
inline __m128 ref_lo_xyz(const PrimRef& r) {
  return _mm_and_ps(_mm_load_ps(r.lo), _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0)));
}
__attribute__((target("avx2"), always_inline)) inline __m256 ref_xyz(__m256 v) {
  return _mm256_and_ps(v, _mm256_castsi256_ps(_mm256_setr_epi32(-1, -1, -1, 0, -1, -1, -1, -1)));
}

/// Plain box without initialisers, for the per-node bin arrays (only bins_ entries are
/// initialised per node; a default-constructed array of 3 x 256 boxes would cost more than the
/// binning itself on small nodes).
struct RawBox {
  __m128 lo, hi;
};

struct Box4 {
  __m128 lo = _mm_set1_ps(kInf);
  __m128 hi = _mm_set1_ps(-kInf);

  void grow(__m128 l, __m128 h) {
    lo = _mm_min_ps(lo, l);
    hi = _mm_max_ps(hi, h);
  }
  void grow(const Box4& b) { grow(b.lo, b.hi); }
  void grow(const RawBox& b) { grow(b.lo, b.hi); }
  Box4() = default;
  explicit Box4(const RawBox& b) : lo(b.lo), hi(b.hi) {}
  /// Half surface area (the factor 2 cancels in every SAH ratio); 0 when empty.
  float half_area() const {
    alignas(16) float l[4], h[4];
    _mm_store_ps(l, lo);
    _mm_store_ps(h, hi);
    const float ex = h[0] - l[0], ey = h[1] - l[1], ez = h[2] - l[2];
    if (!(ex >= 0.0f && ey >= 0.0f && ez >= 0.0f)) return 0.0f;
    return ex * ey + ey * ez + ez * ex;
  }
  Aabb aabb() const {
    alignas(16) float l[4], h[4];
    _mm_store_ps(l, lo);
    _mm_store_ps(h, hi);
    Aabb b;
    b.min = {l[0], l[1], l[2]};
    b.max = {h[0], h[1], h[2]};
    return b;
  }
};

/// Vertex \p v of \p pos (\p vcount vertices) as (x, y, z, junk) in one 16-byte load, which
/// reads the next vertex's x as lane 3; the last vertex, whose 4 bytes after it are not ours,
/// is assembled with lane 3 = 0 instead.
inline __m128 load_vertex(const Vec3* pos, size_t vcount, uint32_t v) {
  return v + 1 < vcount ? _mm_loadu_ps(&pos[v].x) : _mm_setr_ps(pos[v].x, pos[v].y, pos[v].z, 0.0f);
}

/// Half surface area of a non-empty box, all in registers (the sweeps call this ~2 x bins x 3
/// times per node, which is most of the build time on small nodes).
inline float half_area4(__m128 lo, __m128 hi) {
  const __m128 e = _mm_sub_ps(hi, lo);
  const __m128 p = _mm_mul_ps(e, _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1)));  // ex*ey, ey*ez, ez*ex
  const __m128 s = _mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1)));
  return _mm_cvtss_f32(_mm_add_ss(s, _mm_movehl_ps(p, p)));
}

constexpr int kMaxBins = 256;
/// Leaves are tested four triangles at a time (BvhTriangle4), so the SAH charges a leaf by its
/// blocks of four, as Embree's BVH4/Triangle4 builder does: splitting four triangles or fewer
/// can never pay off, and leaves fill up to whole blocks.
constexpr uint32_t kBlock = 4;
inline float blocks(uint32_t n) { return static_cast<float>((n + kBlock - 1) / kBlock); }
/// Subtrees with more primitives than this are spawned as TBB tasks.
constexpr uint32_t kTaskThreshold = 4096;
/// Nodes with at least this many primitives bin them on all threads (AVX2 split search), in
/// chunks of kBinChunk.
constexpr uint32_t kParallelBinMin = 1u << 15;
constexpr uint32_t kBinChunk = 1u << 13;
/// Triangle blocks filled per task when the build has threads.
constexpr uint32_t kFillChunk = 1u << 12;
/// Binary trees of at least this many nodes run the collapse's programme on all threads.
constexpr size_t kParallelDpMin = size_t{1} << 13;
/// Beyond this depth the builder stops using SAH and halves index ranges, which bounds the
/// depth (and so the traversal stack) at kMedianDepth + 32 whatever the input.
constexpr uint32_t kMedianDepth = 64;

/// half_area4 of three (lo, -hi) boxes at once (lane a = box a; lane 3 is junk), bit for bit.
__attribute__((target("avx2"))) inline __m128 half_area_x3(__m256 b0, __m256 b1, __m256 b2) {
  const __m128 e0 = _mm_add_ps(_mm256_castps256_ps128(b0), _mm256_extractf128_ps(b0, 1));
  const __m128 e1 = _mm_add_ps(_mm256_castps256_ps128(b1), _mm256_extractf128_ps(b1, 1));
  const __m128 e2 = _mm_add_ps(_mm256_castps256_ps128(b2), _mm256_extractf128_ps(b2, 1));
  const __m128 t0 = _mm_unpacklo_ps(e0, e1), t1 = _mm_unpackhi_ps(e0, e1);  // x0 x1 y0 y1 | z0 z1 . .
  const __m128 t2 = _mm_unpacklo_ps(e2, e2), t3 = _mm_unpackhi_ps(e2, e2);  // x2 x2 y2 y2 | z2 z2 . .
  const __m128 ex = _mm_movelh_ps(t0, t2), ey = _mm_movehl_ps(t2, t0), ez = _mm_movelh_ps(t1, t3);
  return _mm_add_ps(_mm_add_ps(_mm_mul_ps(ex, ey), _mm_mul_ps(ey, ez)), _mm_mul_ps(ez, ex));
}

/// _mm256_blendv_ps(a, b, mask) as one instruction. GCC 12 lowers the intrinsic to a select
/// on "mask < 0" and, not knowing that a permuted compare result is all ones or all zeros,
/// rebuilds the mask with a vpcmpgtd per call (one of ~25 instructions per reference in the
/// partition loop).
__attribute__((target("avx2"), always_inline)) inline __m256 blendv_asm(__m256 a, __m256 b, __m256 mask) {
  __m256 r;
  __asm__("vblendvps %3, %2, %1, %0" : "=x"(r) : "x"(a), "x"(b), "x"(mask));
  return r;
}

/// One bin of the AVX2 split search: its (lo, -hi) box and primitive count, 64 bytes so that a
/// bin index scaled by 64 addresses both.
struct alignas(64) BinRec {
  __m256 box;
  uint32_t count;
  uint32_t pad[7];
};
static_assert(sizeof(BinRec) == 64);

/// Byte offsets of a reference's bins on the three axes (lanes 0-2): the bin index of its
/// doubled centroid, as BinParams computes it, times 64, plus the axis' offset.
__attribute__((target("avx2"), always_inline)) inline __m128i bin_offsets(__m256 v, __m128 vmin, __m128 vscale,
                                                                          __m128 vmaxbin, __m128i voff64) {
  const __m128 c = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
  return _mm_add_epi32(
      _mm_slli_epi32(_mm_cvttps_epi32(_mm_min_ps(_mm_mul_ps(_mm_sub_ps(c, vmin), vscale), vmaxbin)), 6), voff64);
}

/// Grows the bin at byte offset off from base by the (lo, -hi) box v.
__attribute__((target("avx2"), always_inline)) inline void bin_update(char* base, uint32_t off, __m256 v) {
  BinRec& r = *reinterpret_cast<BinRec*>(base + off);
  r.box = _mm256_min_ps(r.box, v);
  ++r.count;
}

struct Split {
  int axis = -1;
  int bin = 0;  ///< primitives with bin index < bin go left
  float cost = kInf;  ///< left_area * left_blocks + right_area * right_blocks (half areas)
  Box4 left, right;
  uint32_t left_count = 0;
  float bin_min = 0.0f, bin_scale = 0.0f;  ///< binning parameters of the chosen axis
  int bin_count = 0;
};

/// Binning parameters of one node, shared by the SSE2 and AVX2 split searches: bin count,
/// centroid bounds, bin scale per axis. The bin count grows with the node, 4 + n / 20 up to
/// BvhOptions::bins, as Embree's binned builder chooses it: the sweeps and the bin set-up cost
/// per bin, and dominated the build time on the many small nodes, while a few bins find the
/// split of a few triangles about as well (bunny, leaves of at most 16: SAH cost 36.50 with at
/// most 32 bins, against 36.68 with min(12, n) bins, and fewer nodes visited and triangles
/// tested per ray).
/// Bin index vector -> packed index: axis a's bins at a * nb (a few cache lines instead of
/// 3 x 256 bins spaced apart, whose equal low address bits made loads of one axis wait on
/// stores of another: 4K aliasing). Lane 3 is never read.
struct BinParams {
  alignas(16) float cmin[4], cext[4], scale[4];
  int nb;
  __m128 vmin, vscale, vmaxbin;
  __m128i voff;

  BinParams(int bins, uint32_t count, const Box4& cbounds) {
    _mm_store_ps(cmin, cbounds.lo);
    _mm_store_ps(cext, _mm_sub_ps(cbounds.hi, cbounds.lo));
    nb = std::min(bins, 4 + static_cast<int>(count / 20));
    const float fbins = static_cast<float>(nb);
    for (int a = 0; a < 3; ++a) scale[a] = cext[a] > 0.0f ? fbins / cext[a] : 0.0f;
    scale[3] = 0.0f;
    vmin = cbounds.lo;
    vscale = _mm_load_ps(scale);
    vmaxbin = _mm_set1_ps(fbins - 1.0f);
    voff = _mm_setr_epi32(0, nb, 2 * nb, 0);
  }
};

}  // namespace

class BvhBuilder {
 public:
  BvhBuilder(const BvhOptions& options, PrimRef* refs, BvhNode* nodes, uint32_t* prim_ids)
      : refs_(refs), nodes_(nodes), prim_ids_(prim_ids), bins_(std::clamp(options.bins, 2, kMaxBins)),
        max_leaf_(static_cast<uint32_t>(std::clamp(options.max_leaf_size, 1, 1 << 20))),
        traversal_cost_(std::isfinite(options.traversal_cost) && options.traversal_cost >= 0.0f
                            ? options.traversal_cost
                            : 1.0f) {}

  uint32_t node_count() const { return next_node_.load(); }

  /// Builds the whole tree over refs[0, count); node 0 is the root.
  void build_root(uint32_t count, const Box4& bounds, const Box4& cbounds, bool parallel) {
    next_node_ = 2;  // node 1 is padding: keeps sibling pairs on one cache line
    parallel_ = parallel;
    if (parallel) {
      tbb::task_group tg;
      build(0, 0, count, bounds, cbounds, 0, &tg);
      tg.wait();
    } else {
      build(0, 0, count, bounds, cbounds, 0, nullptr);
    }
  }

 private:
  /// Also writes the leaf's scene indices in BVH order: its references were just partitioned
  /// (in cache), where a pass over all of them afterwards read 32 bytes per triangle again.
  void make_leaf(BvhNode& node, uint32_t first, uint32_t count) const {
    node.left_first = first;
    node.count = count;
    for (uint32_t i = first; i < first + count; ++i) prim_ids_[i] = refs_[i].id();
  }

  static void store_box(BvhNode& node, const Box4& b) {
    const Aabb a = b.aabb();
    node.min = a.min;
    node.max = a.max;
  }

  /// Bins [first, first + count) on every axis with non-zero centroid extent and returns the
  /// cheapest split (axis -1 when all centroids coincide).
  __attribute__((noinline)) Split find_split(uint32_t first, uint32_t count, const Box4& cbounds) const {
    const BinParams bp(bins_, count, cbounds);
    const int nb = bp.nb;
    const float *cmin = bp.cmin, *cext = bp.cext, *scale = bp.scale;
    const __m128 vmin = bp.vmin, vscale = bp.vscale, vmaxbin = bp.vmaxbin;
    const __m128i voff = bp.voff;

    // Large nodes bin into two sets (even / odd primitives), as Embree does: consecutive
    // primitives are spatially close and often land in the same bin, and one set would chain
    // every update on the store of the previous one. Counts live apart from the boxes.
    const int sets = count >= 64 ? 2 : 1;
    const int stride = 3 * nb;
    RawBox box[2 * 3 * kMaxBins];
    alignas(16) uint32_t cnt[2 * 3 * kMaxBins];
    const __m128 empty_lo = _mm_set1_ps(kInf), empty_hi = _mm_set1_ps(-kInf);
    for (int i = 0; i < sets * stride; ++i) box[i] = {empty_lo, empty_hi}, cnt[i] = 0;
    const PrimRef* refs = refs_ + first;
    const auto bin_of = [&](const PrimRef& r, __m128& lo, __m128& hi) {
      lo = ref_lo_xyz(r), hi = _mm_load_ps(r.hi);
      const __m128 f = _mm_min_ps(_mm_mul_ps(_mm_sub_ps(_mm_add_ps(lo, hi), vmin), vscale), vmaxbin);
      return _mm_add_epi32(_mm_cvttps_epi32(f), voff);
    };
    const auto add = [&](RawBox* bx, uint32_t* cn, __m128i bi, __m128 lo, __m128 hi) {
      const int b0 = _mm_cvtsi128_si32(bi);
      const int b1 = _mm_cvtsi128_si32(_mm_shuffle_epi32(bi, _MM_SHUFFLE(1, 1, 1, 1)));
      const int b2 = _mm_cvtsi128_si32(_mm_shuffle_epi32(bi, _MM_SHUFFLE(2, 2, 2, 2)));
      bx[b0].lo = _mm_min_ps(bx[b0].lo, lo), bx[b0].hi = _mm_max_ps(bx[b0].hi, hi), ++cn[b0];
      bx[b1].lo = _mm_min_ps(bx[b1].lo, lo), bx[b1].hi = _mm_max_ps(bx[b1].hi, hi), ++cn[b1];
      bx[b2].lo = _mm_min_ps(bx[b2].lo, lo), bx[b2].hi = _mm_max_ps(bx[b2].hi, hi), ++cn[b2];
    };
    uint32_t i = 0;
    if (sets == 2) {
      for (; i + 1 < count; i += 2) {
        __m128 lo0, hi0, lo1, hi1;
        const __m128i b0 = bin_of(refs[i], lo0, hi0), b1 = bin_of(refs[i + 1], lo1, hi1);
        add(box, cnt, b0, lo0, hi0);
        add(box + stride, cnt + stride, b1, lo1, hi1);
      }
      for (int k = 0; k < 3 * nb; ++k) {
        box[k].lo = _mm_min_ps(box[k].lo, box[stride + k].lo);
        box[k].hi = _mm_max_ps(box[k].hi, box[stride + k].hi);
        cnt[k] += cnt[stride + k];
      }
    }
    for (; i < count; ++i) {
      __m128 lo, hi;
      const __m128i b = bin_of(refs[i], lo, hi);
      add(box, cnt, b, lo, hi);
    }

    // Sweeps: right to left for the right sides' costs, then left to right; only the cost is
    // kept per plane, the winner's boxes are gathered from its bins afterwards.
    float best_cost = kInf;
    int best_axis = -1, best_bin = 0;
    float right_cost[kMaxBins];
    for (int a = 0; a < 3; ++a) {
      if (!(cext[a] > 0.0f)) continue;
      const RawBox* bx = box + a * nb;
      const uint32_t* cn = cnt + a * nb;
      __m128 rlo = empty_lo, rhi = empty_hi;
      uint32_t n = 0;
      for (int k = nb - 1; k > 0; --k) {
        rlo = _mm_min_ps(rlo, bx[k].lo), rhi = _mm_max_ps(rhi, bx[k].hi);
        n += cn[k];
        right_cost[k] = n == 0 ? kInf : half_area4(rlo, rhi) * blocks(n);
      }
      __m128 llo = empty_lo, lhi = empty_hi;
      uint32_t ln = 0;
      for (int k = 1; k < nb; ++k) {
        llo = _mm_min_ps(llo, bx[k - 1].lo), lhi = _mm_max_ps(lhi, bx[k - 1].hi);
        ln += cn[k - 1];
        if (ln == 0 || right_cost[k] == kInf) continue;
        const float cost = half_area4(llo, lhi) * blocks(ln) + right_cost[k];
        if (cost < best_cost) best_cost = cost, best_axis = a, best_bin = k;
      }
    }
    Split best;
    if (best_axis >= 0) {
      best.cost = best_cost;
      best.axis = best_axis;
      best.bin = best_bin;
      const RawBox* bx = box + best_axis * nb;
      const uint32_t* cn = cnt + best_axis * nb;
      for (int k = 0; k < best_bin; ++k) best.left.grow(bx[k]), best.left_count += cn[k];
      for (int k = best_bin; k < nb; ++k) best.right.grow(bx[k]);
      best.bin_min = cmin[best_axis];
      best.bin_scale = scale[best_axis];
      best.bin_count = nb;
    }
    return best;
  }

  // AVX2 variants of find_split and partition (same arithmetic, so the same tree). A bin is one
  // 256-bit register (lo.xyzw, -hi.xyzw): a single min grows both corners (-max(a, b) is
  // exactly min(-a, -b)), and a primitive reference is a single 32-byte load.
  /// Bins \p count references from \p refs into rec[0, 3 * nb) (AVX2 layout; rec has room for
  /// 2 * 3 * nb records, the second half scratch).
  __attribute__((target("avx2"))) static void bin_refs_avx2(const PrimRef* refs, uint32_t count, const BinParams& bp,
                                                             BinRec* rec) {
    const int nb = bp.nb;
    const __m128 vmin = bp.vmin, vscale = bp.vscale, vmaxbin = bp.vmaxbin;
    const __m128i voff = bp.voff;
    const __m256 neg_hi = _mm256_setr_ps(0.0f, 0.0f, 0.0f, 0.0f, -0.0f, -0.0f, -0.0f, -0.0f);
    const __m256 empty = _mm256_set1_ps(kInf);
    // A bin is one 64-byte record (box, count), addressed by byte offset: the bin index
    // vector is scaled to bytes before the three lanes are extracted, so each update is a
    // min from memory, a store and an increment at the same address (no index arithmetic).
    const int sets = count >= 64 ? 2 : 1;
    const int stride = 3 * nb;
#pragma GCC unroll 2
    for (int i = 0; i < sets * stride; ++i) rec[i].box = empty, rec[i].count = 0;
    const __m128i voff64 = _mm_slli_epi32(voff, 6);
    char* const base0 = reinterpret_cast<char*>(rec);
    uint32_t i = 0;
    if (sets == 2) {
      char* const base1 = base0 + static_cast<size_t>(stride) * sizeof(BinRec);
      for (; i + 1 < count; i += 2) {
        const __m256 v0 = ref_xyz(_mm256_load_ps(refs[i].lo)), v1 = ref_xyz(_mm256_load_ps(refs[i + 1].lo));
        const __m128i o0 = bin_offsets(v0, vmin, vscale, vmaxbin, voff64),
                      o1 = bin_offsets(v1, vmin, vscale, vmaxbin, voff64);
        const __m256 n0 = _mm256_xor_ps(v0, neg_hi), n1 = _mm256_xor_ps(v1, neg_hi);
        bin_update(base0, static_cast<uint32_t>(_mm_cvtsi128_si32(o0)), n0);
        bin_update(base1, static_cast<uint32_t>(_mm_cvtsi128_si32(o1)), n1);
        bin_update(base0, static_cast<uint32_t>(_mm_extract_epi32(o0, 1)), n0);
        bin_update(base1, static_cast<uint32_t>(_mm_extract_epi32(o1, 1)), n1);
        bin_update(base0, static_cast<uint32_t>(_mm_extract_epi32(o0, 2)), n0);
        bin_update(base1, static_cast<uint32_t>(_mm_extract_epi32(o1, 2)), n1);
      }
      for (int k = 0; k < stride; ++k)
        rec[k].box = _mm256_min_ps(rec[k].box, rec[stride + k].box), rec[k].count += rec[stride + k].count;
    }
    for (; i < count; ++i) {
      const __m256 v = ref_xyz(_mm256_load_ps(refs[i].lo));
      const __m128i o = bin_offsets(v, vmin, vscale, vmaxbin, voff64);
      const __m256 nv = _mm256_xor_ps(v, neg_hi);
      bin_update(base0, static_cast<uint32_t>(_mm_cvtsi128_si32(o)), nv);
      bin_update(base0, static_cast<uint32_t>(_mm_extract_epi32(o, 1)), nv);
      bin_update(base0, static_cast<uint32_t>(_mm_extract_epi32(o, 2)), nv);
    }
  }

  __attribute__((target("avx2"), noinline)) Split find_split_avx2(uint32_t first, uint32_t count,
                                                                   const Box4& cbounds) const {
    const BinParams bp(bins_, count, cbounds);
    const int nb = bp.nb;
    const float *cmin = bp.cmin, *cext = bp.cext;
    const float* scale = bp.scale;
    const __m256 neg_hi = _mm256_setr_ps(0.0f, 0.0f, 0.0f, 0.0f, -0.0f, -0.0f, -0.0f, -0.0f);
    const __m256 empty = _mm256_set1_ps(kInf);
    const int stride = 3 * nb;
    BinRec rec[2 * 3 * kMaxBins];
    const PrimRef* refs = refs_ + first;
    if (parallel_ && count >= kParallelBinMin) {
      // Large nodes (the top of the tree, which no other task overlaps) bin in fixed chunks on
      // every thread. A bin's box is a min over its references and its count a sum, both
      // exact in any order, so the merged bins (and the tree) are the serial pass's.
      const uint32_t chunks = (count + kBinChunk - 1) / kBinChunk;
      std::vector<BinRec> part(size_t{chunks} * 2 * static_cast<size_t>(stride));
      tbb::parallel_for(tbb::blocked_range<uint32_t>(0, chunks, 1), [&](const tbb::blocked_range<uint32_t>& r) {
        for (uint32_t c = r.begin(); c != r.end(); ++c)
          bin_refs_avx2(refs + size_t{c} * kBinChunk, std::min(kBinChunk, count - c * kBinChunk), bp,
                        part.data() + size_t{c} * 2 * static_cast<size_t>(stride));
      });
      for (int k = 0; k < stride; ++k) {
        __m256 box = empty;
        uint32_t n = 0;
        for (uint32_t c = 0; c < chunks; ++c) {
          const BinRec& b = part[size_t{c} * 2 * static_cast<size_t>(stride) + static_cast<size_t>(k)];
          box = _mm256_min_ps(box, b.box);
          n += b.count;
        }
        rec[k].box = box;
        rec[k].count = n;
      }
    } else {
      bin_refs_avx2(refs, count, bp, rec);
    }

    // Sweeps of the three axes at once, lane a = axis a. Half areas from (lo, -hi): lo + (-hi)
    // is exactly -(hi - lo), the products of two negated extents are the products of the
    // extents, and the sums run in half_area4's order, so every cost has find_split's bits.
    __m128i cntv[kMaxBins];
    for (int k = 0; k < nb; ++k)
      cntv[k] = _mm_setr_epi32(static_cast<int>(rec[k].count), static_cast<int>(rec[nb + k].count),
                               static_cast<int>(rec[2 * nb + k].count), 0);
    const __m128 vinf = _mm_set1_ps(kInf);
    const __m128i three = _mm_set1_epi32(3), zero = _mm_setzero_si128();
    const BinRec* b0 = rec;
    const BinRec* b1 = rec + nb;
    const BinRec* b2 = rec + 2 * nb;
    __m128 rcost[kMaxBins];
    {
      __m256 acc0 = empty, acc1 = empty, acc2 = empty;
      __m128i n = zero;
      for (int k = nb - 1; k > 0; --k) {
        acc0 = _mm256_min_ps(acc0, b0[k].box), acc1 = _mm256_min_ps(acc1, b1[k].box),
        acc2 = _mm256_min_ps(acc2, b2[k].box);
        n = _mm_add_epi32(n, cntv[k]);
        const __m128 area = half_area_x3(acc0, acc1, acc2);
        const __m128 blk = _mm_cvtepi32_ps(_mm_srli_epi32(_mm_add_epi32(n, three), 2));
        rcost[k] = _mm_mul_ps(area, blk);
      }
    }
    // No explicit skip of planes with an empty side (find_split's "n == 0 || right_cost ==
    // kInf"): such a plane's cost here is never below bestc, so the same planes win. An empty
    // side's box is all (inf, inf) (bins are grown together with their counts), so its half
    // area is inf and times 0 blocks NaN; a NaN side makes the cost NaN, and a right cost of
    // inf (empty or overflowed) adds to a left term that is >= 0, inf or NaN, giving inf or NaN.
    // Neither compares below bestc (strict <, starting at inf), exactly as the skipped kInf.
    __m128 bestc = vinf;
    __m128i bestk = zero, kv = zero;
    const __m128i one = _mm_set1_epi32(1);
    {
      __m256 acc0 = empty, acc1 = empty, acc2 = empty;
      __m128i n = zero;
      for (int k = 1; k < nb; ++k) {
        kv = _mm_add_epi32(kv, one);  // k in every lane
        acc0 = _mm256_min_ps(acc0, b0[k - 1].box), acc1 = _mm256_min_ps(acc1, b1[k - 1].box),
        acc2 = _mm256_min_ps(acc2, b2[k - 1].box);
        n = _mm_add_epi32(n, cntv[k - 1]);
        const __m128 area = half_area_x3(acc0, acc1, acc2);
        const __m128 blk = _mm_cvtepi32_ps(_mm_srli_epi32(_mm_add_epi32(n, three), 2));
        const __m128 cost = _mm_add_ps(_mm_mul_ps(area, blk), rcost[k]);
        const __m128 better = _mm_cmplt_ps(cost, bestc);
        bestc = _mm_blendv_ps(bestc, cost, better);
        bestk = _mm_blendv_epi8(bestk, kv, _mm_castps_si128(better));
      }
    }
    alignas(16) float bc[4];
    alignas(16) int32_t bk[4];
    _mm_store_ps(bc, bestc);
    _mm_store_si128(reinterpret_cast<__m128i*>(bk), bestk);
    float best_cost = kInf;
    int best_axis = -1, best_bin = 0;
    for (int a = 0; a < 3; ++a)
      if (cext[a] > 0.0f && bc[a] < best_cost) best_cost = bc[a], best_axis = a, best_bin = bk[a];
    Split best;
    if (best_axis >= 0) {
      best.cost = best_cost;
      best.axis = best_axis;
      best.bin = best_bin;
      const BinRec* bx = rec + best_axis * nb;
      __m256 l = empty, r = empty;
      for (int k = 0; k < best_bin; ++k) l = _mm256_min_ps(l, bx[k].box), best.left_count += bx[k].count;
      for (int k = best_bin; k < nb; ++k) r = _mm256_min_ps(r, bx[k].box);
      l = _mm256_xor_ps(l, neg_hi), r = _mm256_xor_ps(r, neg_hi);
      best.left.lo = _mm256_castps256_ps128(l), best.left.hi = _mm256_extractf128_ps(l, 1);
      best.right.lo = _mm256_castps256_ps128(r), best.right.hi = _mm256_extractf128_ps(r, 1);
      best.bin_min = cmin[best_axis];
      best.bin_scale = scale[best_axis];
      best.bin_count = nb;
    }
    return best;
  }

  __attribute__((target("avx2"))) uint32_t partition_avx2(uint32_t first, uint32_t count, const Split& split,
                                                          Box4& lcb, Box4& rcb) const {
    switch (split.axis) {
      case 0: return partition_axis_avx2<0>(first, count, split, lcb, rcb);
      case 1: return partition_axis_avx2<1>(first, count, split, lcb, rcb);
      default: return partition_axis_avx2<2>(first, count, split, lcb, rcb);
    }
  }

  /// As partition_axis; the centroid bounds of each side are kept as (c, -c) boxes grown by
  /// one blend and one min.
  template <int Axis>
  __attribute__((target("avx2"))) uint32_t partition_axis_avx2(uint32_t first, uint32_t count, const Split& split,
                                                               Box4& lcb, Box4& rcb) const {
    // int(min(x, bins - 1)) < bin  <=>  x < bin for every x (bin <= bins - 1; NaN goes right
    // both ways), so the float compare makes exactly find_split's decision.
    // The test runs on (c, c) in both halves, so its mask is already 256 bits wide for the
    // blends (a 128-bit test needed a lane copy and a sign fix-up, 2 of ~25 instructions).
    const __m256 vmin = _mm256_set1_ps(split.bin_min), vscale = _mm256_set1_ps(split.bin_scale);
    const __m256 vbin = _mm256_set1_ps(static_cast<float>(split.bin));
    const __m256 neg_hi = _mm256_setr_ps(0.0f, 0.0f, 0.0f, 0.0f, -0.0f, -0.0f, -0.0f, -0.0f);
    const __m256 empty = _mm256_set1_ps(kInf);
    __m256 lb = _mm256_xor_ps(_mm256_setr_m128(lcb.lo, lcb.hi), neg_hi);
    __m256 rb = _mm256_xor_ps(_mm256_setr_m128(rcb.lo, rcb.hi), neg_hi);
    // Pointers rather than indices: the left end advances by 0 or 1 element, no index scaling.
    PrimRef* left = refs_ + first;
    PrimRef* const end = left + count;
    for (PrimRef* k = left; k != end; ++k) {
      const __m256 v = _mm256_load_ps(k->lo), vx = ref_xyz(v);
      const __m128 c = _mm_add_ps(_mm256_castps256_ps128(vx), _mm256_extractf128_ps(vx, 1));
      const __m256 c2 = _mm256_setr_m128(c, c);
      const __m256 lt = _mm256_cmp_ps(_mm256_mul_ps(_mm256_sub_ps(c2, vmin), vscale), vbin, _CMP_LT_OQ);
      const __m256 m8 = _mm256_permute_ps(lt, _MM_SHUFFLE(Axis, Axis, Axis, Axis));
      const __m256 cc = _mm256_xor_ps(c2, neg_hi);  // (c, -c)
      lb = _mm256_min_ps(lb, blendv_asm(empty, cc, m8));
      rb = _mm256_min_ps(rb, blendv_asm(cc, empty, m8));
      _mm256_store_ps(k->lo, _mm256_load_ps(left->lo));
      _mm256_store_ps(left->lo, v);
      left += _mm256_movemask_ps(m8) & 1;
    }
    const uint32_t i = static_cast<uint32_t>(left - refs_);
    lb = _mm256_xor_ps(lb, neg_hi), rb = _mm256_xor_ps(rb, neg_hi);
    lcb.lo = _mm256_castps256_ps128(lb), lcb.hi = _mm256_extractf128_ps(lb, 1);
    rcb.lo = _mm256_castps256_ps128(rb), rcb.hi = _mm256_extractf128_ps(rb, 1);
    return i;
  }

  void build(uint32_t node_index, uint32_t first, uint32_t count, const Box4& bounds,
             const Box4& cbounds, uint32_t depth, tbb::task_group* tg) {
    BvhNode& node = nodes_[node_index];
    store_box(node, bounds);
    if (count <= 1 || (count <= kBlock && count <= max_leaf_ && traversal_cost_ >= 1.0f)) {
      // One block: a split costs at least traversal_cost + 1 block, more than the leaf.
      make_leaf(node, first, count);
      return;
    }

    uint32_t mid = 0;
    Box4 lbox, rbox, lcb, rcb;
    bool split_found = false;
    if (count == 2) {
      // Every binned split of two primitives puts one on each side, so its cost is known
      // without binning (a quarter of all nodes; binning them dominated the build time).
      const PrimRef &p0 = refs_[first], &p1 = refs_[first + 1];
      lbox.grow(ref_lo_xyz(p0), _mm_load_ps(p0.hi));
      rbox.grow(ref_lo_xyz(p1), _mm_load_ps(p1.hi));
      const float area = bounds.half_area();
      const float split_cost =
          traversal_cost_ + (area > 0.0f ? (lbox.half_area() + rbox.half_area()) / area : 2.0f);
      if (!(split_cost < blocks(2)) && max_leaf_ >= 2) {
        make_leaf(node, first, count);
        return;
      }
      mid = first + 1;
      split_found = true;
    } else if (depth < kMedianDepth) {
      const Split split = avx2_ ? find_split_avx2(first, count, cbounds) : find_split(first, count, cbounds);
      if (split.axis >= 0) {
        const float leaf_cost = blocks(count);
        const float area = bounds.half_area();
        const float split_cost = traversal_cost_ + (area > 0.0f ? split.cost / area : leaf_cost);
        if (split_cost < leaf_cost || count > max_leaf_) {
          mid = avx2_ ? partition_avx2(first, count, split, lcb, rcb) : partition(first, count, split, lcb, rcb);
          lbox = split.left;
          rbox = split.right;
          split_found = mid > first && mid < first + count;
          if (split_found && mid - first != split.left_count) {
            // Cannot happen (partition repeats the binning arithmetic), but never trust it
            // with the bounds: recompute them from the primitives.
            lbox = rbox = lcb = rcb = Box4{};
            range_bounds(first, mid, lbox, lcb);
            range_bounds(mid, first + count, rbox, rcb);
          }
        } else {
          make_leaf(node, first, count);
          return;
        }
      }
    }
    if (!split_found) {
      lbox = rbox = lcb = rcb = Box4{};
      // All centroids coincide (or depth limit reached): leaf if allowed, else halve the range.
      if (count <= max_leaf_) {
        make_leaf(node, first, count);
        return;
      }
      mid = first + count / 2;
      range_bounds(first, mid, lbox, lcb);
      range_bounds(mid, first + count, rbox, rcb);
    }

    const uint32_t left = next_node_.fetch_add(2, std::memory_order_relaxed);
    node.left_first = left;
    node.count = 0;
    const uint32_t lcount = mid - first, rcount = first + count - mid;
    if (tg && count > kTaskThreshold) {
      tg->run([=, this] { build(left, first, lcount, lbox, lcb, depth + 1, tg); });
      build(left + 1, mid, rcount, rbox, rcb, depth + 1, tg);
    } else {
      build(left, first, lcount, lbox, lcb, depth + 1, tg);
      build(left + 1, mid, rcount, rbox, rcb, depth + 1, tg);
    }
  }

  /// In-place partition of [first, first + count) by the split's bin; returns the first index
  /// of the right side and fills the centroid bounds of both sides. Uses exactly the binning
  /// arithmetic of find_split, so the sides match the counted bins.
  uint32_t partition(uint32_t first, uint32_t count, const Split& split, Box4& lcb, Box4& rcb) const {
    switch (split.axis) {
      case 0: return partition_axis<0>(first, count, split, lcb, rcb);
      case 1: return partition_axis<1>(first, count, split, lcb, rcb);
      default: return partition_axis<2>(first, count, split, lcb, rcb);
    }
  }

  template <int Axis>
  uint32_t partition_axis(uint32_t first, uint32_t count, const Split& split, Box4& lcb, Box4& rcb) const {
    const __m128 vmin = _mm_set1_ps(split.bin_min), vscale = _mm_set1_ps(split.bin_scale);
    const __m128 vmaxbin = _mm_set1_ps(static_cast<float>(split.bin_count) - 1.0f);
    const __m128i vbin = _mm_set1_epi32(split.bin);
    // Branchless Lomuto partition: which side a primitive goes to is a coin flip for the branch
    // predictor, so every element is swapped into place unconditionally and the left end only
    // advances for left elements; centroid bounds are grown through masks.
    const __m128 empty_lo = _mm_set1_ps(kInf), empty_hi = _mm_set1_ps(-kInf);
    __m128 llo = lcb.lo, lhi = lcb.hi, rlo = rcb.lo, rhi = rcb.hi;
    PrimRef* refs = refs_;
    uint32_t i = first;
    for (uint32_t k = first; k < first + count; ++k) {
      const __m128 lo = _mm_load_ps(refs[k].lo), hi = _mm_load_ps(refs[k].hi);
      const __m128 c = _mm_add_ps(ref_lo_xyz(refs[k]), hi);
      // The bin index as find_split computes it (the other lanes are ignored).
      const __m128i b = _mm_cvttps_epi32(_mm_min_ps(_mm_mul_ps(_mm_sub_ps(c, vmin), vscale), vmaxbin));
      const __m128 m = _mm_castsi128_ps(
          _mm_shuffle_epi32(_mm_cmplt_epi32(b, vbin), _MM_SHUFFLE(Axis, Axis, Axis, Axis)));
      const __m128 mc = _mm_and_ps(m, c), nc = _mm_andnot_ps(m, c);
      llo = _mm_min_ps(llo, _mm_or_ps(mc, _mm_andnot_ps(m, empty_lo)));
      lhi = _mm_max_ps(lhi, _mm_or_ps(mc, _mm_andnot_ps(m, empty_hi)));
      rlo = _mm_min_ps(rlo, _mm_or_ps(nc, _mm_and_ps(m, empty_lo)));
      rhi = _mm_max_ps(rhi, _mm_or_ps(nc, _mm_and_ps(m, empty_hi)));
      _mm_store_ps(refs[k].lo, _mm_load_ps(refs[i].lo));
      _mm_store_ps(refs[k].hi, _mm_load_ps(refs[i].hi));
      _mm_store_ps(refs[i].lo, lo);
      _mm_store_ps(refs[i].hi, hi);
      i += static_cast<uint32_t>(_mm_movemask_ps(m)) & 1u;
    }
    lcb.lo = llo, lcb.hi = lhi, rcb.lo = rlo, rcb.hi = rhi;
    return i;
  }

  void range_bounds(uint32_t begin, uint32_t end, Box4& box, Box4& cbox) const {
    for (uint32_t i = begin; i < end; ++i) {
      const __m128 lo = ref_lo_xyz(refs_[i]), hi = _mm_load_ps(refs_[i].hi);
      box.grow(lo, hi);
      const __m128 c = _mm_add_ps(lo, hi);
      cbox.grow(c, c);
    }
  }

  PrimRef* refs_;
  bool avx2_ = __builtin_cpu_supports("avx2");
  bool parallel_ = false;  ///< tasks may run: large nodes bin on all threads
  BvhNode* nodes_;
  uint32_t* prim_ids_;  ///< scene index per BVH position, written by make_leaf
  int bins_;
  uint32_t max_leaf_;
  float traversal_cost_;
  std::atomic<uint32_t> next_node_{2};
};


namespace {

/// The temporary arrays of a build (references, binary nodes before renumbering, collapse
/// tables: ~130 bytes per triangle), kept per calling thread between builds. A rebuild on the
/// same thread (dynamic scenes, zones, benchmarks) reuses memory already faulted in instead of
/// taking a page fault per 4 KiB again (~3 ms of a 17 ms bunny build on this VM); the first
/// build of a thread pays as before. A build that starts while another one on the same thread
/// holds the scratch (TBB may run a task of another build while one waits) gets memory of its
/// own. More than kKeepBytes is released after the build rather than kept.
class BuildScratch {
 public:
  static constexpr int kSlots = 4;
  static constexpr size_t kKeepBytes = size_t{256} << 20;

  /// Storage for at least \p bytes, 64-byte aligned, contents unspecified.
  void* get(int slot, size_t bytes) {
    Block& b = blocks_[slot];
    if (b.bytes < bytes) {
      b.p.reset(static_cast<unsigned char*>(::operator new(bytes, std::align_val_t{64})));
      b.bytes = bytes;
      prepare_for_writes(b.p.get(), bytes);  // first touched by this build
    }
    return b.p.get();
  }
  /// Releases the blocks when they hold more than kKeepBytes together.
  void trim() {
    size_t total = 0;
    for (const Block& b : blocks_) total += b.bytes;
    if (total <= kKeepBytes) return;
    for (Block& b : blocks_) b = Block{};
  }

 private:
  struct Free {
    void operator()(unsigned char* p) const { ::operator delete(p, std::align_val_t{64}); }
  };
  struct Block {
    std::unique_ptr<unsigned char, Free> p;
    size_t bytes = 0;
  };
  Block blocks_[kSlots];
};

/// The calling thread's BuildScratch for one build, or scratch of its own when the thread's
/// is in use (see BuildScratch).
class ScratchLease {
 public:
  ScratchLease() : scratch_(busy() ? &own_ : &local()) {
    if (scratch_ != &own_) busy() = true;
  }
  ~ScratchLease() {
    if (scratch_ == &own_) return;
    scratch_->trim();
    busy() = false;
  }
  ScratchLease(const ScratchLease&) = delete;
  ScratchLease& operator=(const ScratchLease&) = delete;
  BuildScratch* operator->() const { return scratch_; }

 private:
  static BuildScratch& local() {
    thread_local BuildScratch scratch;
    return scratch;
  }
  static bool& busy() {
    thread_local bool in_use = false;
    return in_use;
  }
  BuildScratch own_;
  BuildScratch* scratch_;
};

/// Bounds and centroid bounds of a set of PrimRefs (parallel_reduce body).
struct RootBounds {
  Box4 box, cbox;
  void join(const RootBounds& o) {
    box.grow(o.box);
    cbox.grow(o.cbox);
  }
};

}  // namespace

double binary_sah_cost(std::span<const BvhNode> nodes, float traversal_cost) {
  const double tc = std::isfinite(traversal_cost) && traversal_cost >= 0.0f ? traversal_cost : 1.0;
  const auto area = [](const BvhNode& nd) {
    const Vec3 e = nd.max - nd.min;
    return (e.x >= 0 && e.y >= 0 && e.z >= 0) ? double{e.x} * e.y + double{e.y} * e.z + double{e.z} * e.x : 0.0;
  };
  double sum = 0.0, triangles = 0.0;
  for (size_t j = 0; j < nodes.size(); ++j) {
    if (j == 1) continue;  // padding
    const bool leaf = nodes[j].is_leaf();
    sum += area(nodes[j]) * (leaf ? static_cast<double>(nodes[j].count) : tc);
    triangles += leaf ? nodes[j].count : 0;
  }
  const double root = area(nodes[0]);
  return root > 0.0 ? sum / root : triangles;  // (a flat root: every triangle tested)
}

Bvh Bvh::build(const TriangleInput& input, const BvhOptions& options, BuildInfo* info) {
  const Timer timer;
  if (!bvh_kernel_supported(options.kernel))
    throw Error(std::string("BVH kernel '") + bvh_kernel_name(options.kernel) + "' needs a CPU feature this machine lacks");
  // Validation is fused into the reference pass below (indices in range there; a non-finite
  // vertex always makes its triangle degenerate, so only those are checked for finiteness).
  // Any problem found hands over to accel::validate_input, which throws naming the first one.
  if (input.indices.size() % 3 != 0 || input.indices.size() / 3 > 0xFFFFFFF0u) accel::validate_input(input);
  const size_t tri_count = input.indices.size() / 3;
  const uint32_t n = static_cast<uint32_t>(tri_count);
  const int threads = options.threads > 0 ? options.threads : tbb::info::default_concurrency();
  const bool parallel = threads > 1;

  Bvh bvh;
  bvh.tris_ = std::make_shared<TriangleCache>();
  // Taken on the calling thread, before the arena (whose functor may run on another thread).
  const ScratchLease scratch;
  tbb::task_arena arena(threads);
  arena.execute([&] {
    // 1. Primitive references and root bounds. Degenerate triangles get no reference (see
    //    accel::is_degenerate); the references of the others are compacted afterwards.
    // PrimRef and BvhNode are plain data (trivially copyable, no constructors to run).
    static_assert(std::is_trivially_copyable_v<PrimRef> && std::is_trivially_copyable_v<BvhNode>);
    PrimRef* const refs = static_cast<PrimRef*>(scratch->get(0, sizeof(PrimRef) * std::max<size_t>(tri_count, 1)));
    std::unique_ptr<uint8_t[]> degenerate(new uint8_t[tri_count > 0 ? tri_count : 1]);
    std::atomic<bool> invalid{false};
    const size_t vcount = input.positions.size();
    // compact (serial pass): references are written packed at refs[*compact] and the degenerate
    // flags are not needed; otherwise at refs[i], compacted afterwards.
    const auto make_refs = [&](uint32_t begin, uint32_t end, RootBounds& rb, uint32_t* compact) {
      // All in SSE2, computing exactly the floats of accel::is_degenerate and of Vec3 min/max
      // (std::min(x, y) is _mm_min_ps(y, x), std::max(x, y) is _mm_max_ps(y, x)).
      static_assert(sizeof(Vec3) == 3 * sizeof(float));
      const __m128 xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));
      // Plain pointers and a local count: the reference stores (__m128, which may alias
      // anything) made the compiler reload the spans' pointers and keep *compact in memory,
      // a store-forwarding wait per triangle.
      const uint32_t* const idx = input.indices.data();
      const Vec3* const pos = input.positions.data();
      uint32_t packed = compact ? *compact : 0;
      const auto load = [&](uint32_t v) { return _mm_and_ps(load_vertex(pos, vcount, v), xyz); };  // lane 3 = 0
      Box4 box, cbox;  // in registers for the loop; rb is behind a reference
      for (uint32_t i = begin; i < end; ++i) {
        const uint32_t i0 = idx[3 * size_t{i}], i1 = idx[3 * size_t{i} + 1], i2 = idx[3 * size_t{i} + 2];
        if (i0 >= vcount || i1 >= vcount || i2 >= vcount) [[unlikely]] {
          invalid.store(true, std::memory_order_relaxed);
          if (!compact) degenerate[i] = 1;
          continue;
        }
        const __m128 a = load(i0), b = load(i1), c = load(i2);
        // cross(b - a, c - a) lane by lane, then dot(n, n) summed as (x + y) + z.
        const __m128 e1 = _mm_sub_ps(b, a), e2 = _mm_sub_ps(c, a);
        const __m128 nrm = _mm_sub_ps(
            _mm_mul_ps(_mm_shuffle_ps(e1, e1, _MM_SHUFFLE(3, 0, 2, 1)), _mm_shuffle_ps(e2, e2, _MM_SHUFFLE(3, 1, 0, 2))),
            _mm_mul_ps(_mm_shuffle_ps(e1, e1, _MM_SHUFFLE(3, 1, 0, 2)), _mm_shuffle_ps(e2, e2, _MM_SHUFFLE(3, 0, 2, 1))));
        const __m128 sq = _mm_mul_ps(nrm, nrm);
        const float d = _mm_cvtss_f32(_mm_add_ss(_mm_add_ss(sq, _mm_shuffle_ps(sq, sq, _MM_SHUFFLE(1, 1, 1, 1))),
                                                 _mm_movehl_ps(sq, sq)));
        const bool degen = !(d > 0.0f && d < kInf);
        if (!compact) degenerate[i] = degen ? 1 : 0;
        if (degen) {
          const Vec3 &pa = pos[i0], &pb = pos[i1], &pc = pos[i2];
          if (!is_finite(pa) || !is_finite(pb) || !is_finite(pc)) invalid.store(true, std::memory_order_relaxed);
          continue;
        }
        PrimRef& r = refs[compact ? packed++ : i];
        // Lane 3: the index bits in the stored lo, 0 in hi (and in l4, which the sums use).
        const __m128 l4 = _mm_min_ps(_mm_min_ps(c, b), a);
        const __m128 h4 = _mm_max_ps(_mm_max_ps(c, b), a);
        _mm_store_ps(r.lo, _mm_or_ps(l4, _mm_castsi128_ps(_mm_setr_epi32(0, 0, 0, static_cast<int>(i)))));
        _mm_store_ps(r.hi, h4);
        box.grow(l4, h4);
        const __m128 c4 = _mm_add_ps(l4, h4);
        cbox.grow(c4, c4);
      }
      if (compact) *compact = packed;
      rb.box.grow(box);
      rb.cbox.grow(cbox);
    };
    RootBounds root;
    uint32_t valid = 0;
    const bool parallel_refs = parallel && n > kTaskThreshold;
    if (parallel_refs) {
      root = tbb::parallel_reduce(
          tbb::blocked_range<uint32_t>(0, n, 1024), RootBounds{},
          [&](const tbb::blocked_range<uint32_t>& r, RootBounds rb) {
            make_refs(r.begin(), r.end(), rb, nullptr);
            return rb;
          },
          [](RootBounds a, const RootBounds& b) {
            a.join(b);
            return a;
          });
    } else {
      make_refs(0, n, root, &valid);
    }
    if (!invalid.load() && !input.transmittance.empty()) {
      if (input.transmittance.size() != tri_count) invalid = true;
      for (const Vec3& t : input.transmittance)
        if (!is_finite(t) || t.x < 0.0f || t.y < 0.0f || t.z < 0.0f) invalid = true;
    }
    if (invalid.load()) {
      accel::validate_input(input);  // throws, naming the first problem
      throw Error("triangle input: invalid");
    }
    if (parallel_refs) {
      for (uint32_t i = 0; i < n; ++i) {
        if (degenerate[i]) continue;
        if (valid != i) refs[valid] = refs[i];
        ++valid;
      }
    }
    // (Lane 3 of the bounds carries id bits; nothing reads it: only xyz reach the nodes.)

    // 2. Tree. At most 2n - 1 nodes plus the padding node.
    const size_t max_nodes = std::max<size_t>(2 * size_t{valid}, 2);
    // Raw storage: value-initialising 2n nodes would write (and fault in) several MB of which
    // only the used part is ever read; every used node is written by the builder.
    static_assert(alignof(BvhNode) <= 64);
    BvhNode* const node_storage = static_cast<BvhNode*>(scratch->get(1, max_nodes * sizeof(BvhNode)));
    bvh.prim_ids_.reserve(valid);
    prepare_for_writes(bvh.prim_ids_.data(), size_t{valid} * sizeof(uint32_t));
    bvh.prim_ids_.resize(valid);
    // BvhQuality::High builds down to single triangles: reinsertion moves whole subtrees, so
    // it can only regroup triangles that are leaves of their own, and the collapse below makes
    // the leaves (any subtree of at most max_leaf_size triangles, by SAH).
    BvhOptions tree_options = options;
    if (options.quality == BvhQuality::High) tree_options.max_leaf_size = 1;
    BvhBuilder builder(tree_options, refs, node_storage, bvh.prim_ids_.data());
    builder.build_root(valid, root.box, root.cbox, parallel && valid > kTaskThreshold);
    const uint32_t used = builder.node_count();
    bvh.nodes_.reserve(used);
    prepare_for_writes(bvh.nodes_.data(), size_t{used} * sizeof(BvhNode));
    if (!parallel || valid <= kTaskThreshold) {
      bvh.nodes_.assign(node_storage, node_storage + used);
    } else {
      // Tasks allocated node pairs in whatever order they ran: renumber depth-first (left
      // subtree first), which is exactly the single-threaded layout, so the node array is
      // identical for any thread count and subtrees are contiguous in memory.
      bvh.nodes_.resize(used);
      bvh.nodes_[0] = node_storage[0];
      uint32_t next = 2;
      std::vector<std::pair<uint32_t, uint32_t>> todo{{0u, 0u}};  // (old index, new index)
      while (!todo.empty()) {
        const auto [old_index, new_index] = todo.back();
        todo.pop_back();
        const BvhNode& src = node_storage[old_index];
        if (src.is_leaf()) continue;
        const uint32_t left = next;
        next += 2;
        bvh.nodes_[new_index].left_first = left;
        bvh.nodes_[left] = node_storage[src.left_first];
        bvh.nodes_[left + 1] = node_storage[src.left_first + 1];
        todo.push_back({src.left_first + 1, left + 1});
        todo.push_back({src.left_first, left});
      }
    }
    bvh.nodes_[1] = BvhNode{};
    if (valid == 0) bvh.nodes_[0] = BvhNode{};

    // 2b. BvhQuality::High: subtree reinsertion on the binary tree (bvh_optimize.h). It keeps
    //     the layout (depth-first numbering, contiguous subtree ranges) that the collapse
    //     below relies on, and the depth bound the traversal stacks are sized for.
    if (options.quality == BvhQuality::High && valid > 0) {
      const Timer opt;
      bvh.info_.sah_cost_binned = binary_sah_cost(bvh.nodes_, options.traversal_cost);
      const accel::ReinsertionStats rs = accel::optimize_by_reinsertion(bvh.nodes_, bvh.prim_ids_, kMedianDepth + 32);
      bvh.info_.reinsertions = rs.moves;
      bvh.info_.optimize_ms = opt.ms();
    }

    // 3. The transmittance. (The scene index of every triangle in BVH order came from the
    //    builder's leaves. No BvhTriangle array: the leaves' blocks are filled straight from
    //    the input below, and triangles() copies them out only when asked; writing 36 bytes
    //    per triangle that no query reads cost ~8% of the bunny build.)
    const bool any_transparent =
        std::any_of(input.transmittance.begin(), input.transmittance.end(),
                    [](const Vec3& t) { return !accel::is_opaque(t); });
    if (any_transparent) bvh.transmittance_.assign(input.transmittance.begin(), input.transmittance.end());
  });

  // 4. The wide traversal layout of the kernel: collapse the binary tree into nodes of up to W
  //    children, choosing which descendants become a node's children by the least SAH cost
  //    (a dynamic programme over the binary tree, below).
  bvh.kernel_ = resolve_bvh_kernel(options.kernel);
  bvh.packets_ = options.packets;
  if (!bvh.prim_ids_.empty()) {
    const auto& bin = bvh.nodes_;
    const auto half_area_of = [&bin](uint32_t i) {
      const Vec3 e = bin[i].max - bin[i].min;
      return e.x * e.y + e.y * e.z + e.z * e.x;
    };
    // Triangle blocks of the leaves, in the order the collapse meets them (depth first). The
    // collapse only numbers them and notes each lane's scene index (kNoHit: padding) in the
    // free reference scratch; they are filled afterwards in one pass in block order, which can
    // prefetch the vertices of the blocks ahead. (Gathering them as the collapse met the
    // leaves waited on two dependent cache misses per triangle: index, then vertex.)
    const uint32_t* const ids = bvh.prim_ids_.data();
    uint32_t* const lanes = static_cast<uint32_t*>(scratch->get(0, sizeof(uint32_t) * kBlock * bvh.prim_ids_.size()));
    uint32_t block_count = 0;
    const auto make_blocks = [&](uint32_t first, uint32_t count) {
      const uint32_t index = block_count;
      uint32_t* out = lanes + size_t{kBlock} * index;
      const uint32_t padded = (count + kBlock - 1) / kBlock * kBlock;
      for (uint32_t i = 0; i < padded; ++i) out[i] = i < count ? ids[first + i] : kNoHit;
      block_count += padded / kBlock;
      return index;
    };
    const auto fill_blocks = [&] {
      auto& tri4 = bvh.tri4_;
      tri4.reserve(block_count);
      prepare_for_writes(tri4.data(), block_count * sizeof(BvhTriangle4));
      tri4.resize(block_count);  // default-initialised (AlignedAllocator): every block is written below
      BvhTriangle4* const out_blocks = tri4.data();
      const uint32_t* const idx = input.indices.data();
      const Vec3* const pos = input.positions.data();
      const size_t vcount = input.positions.size();
      const __m128 nan4 = _mm_set1_ps(std::numeric_limits<float>::quiet_NaN());
      // Prefetch distances in blocks: the index triples well ahead, the vertices they name a
      // little ahead (as the BVH-order copy of the triangles did before).
      constexpr uint32_t kAheadIdx = 6, kAheadPos = 2;
      // Blocks [begin, block_end); each depends only on its lanes, so ranges run on any thread.
      const auto fill_range = [&](uint32_t begin, uint32_t block_end) {
        for (uint32_t b = begin; b < block_end; ++b) {
          if (b + kAheadIdx < block_end)
            for (uint32_t lane = 0; lane < kBlock; ++lane) {
              const uint32_t id = lanes[size_t{kBlock} * (b + kAheadIdx) + lane];
              if (id != kNoHit) __builtin_prefetch(idx + 3 * size_t{id});
            }
          if (b + kAheadPos < block_end)
            for (uint32_t lane = 0; lane < kBlock; ++lane) {
              const uint32_t id = lanes[size_t{kBlock} * (b + kAheadPos) + lane];
              if (id == kNoHit) continue;
              const uint32_t* ix = idx + 3 * size_t{id};
              __builtin_prefetch(pos + ix[0]);
              __builtin_prefetch(pos + ix[1]);
              __builtin_prefetch(pos + ix[2]);
            }
          // As accel::fill_block, into a local stored once into the array: the lanes' vertices
          // transposed with SSE, (x, y, z, -) per lane -> v[vertex][axis][lane], NaN in unused
          // lanes.
          BvhTriangle4 blk;
          __m128 p[3][4];
          for (uint32_t lane = 0; lane < kBlock; ++lane) {
            const uint32_t id = lanes[size_t{kBlock} * b + lane];
            blk.index[lane] = id;
            const bool on = id != kNoHit;
            const uint32_t* ix = idx + 3 * size_t{on ? id : 0};
            for (int k = 0; k < 3; ++k) p[k][lane] = on ? load_vertex(pos, vcount, ix[k]) : nan4;  // lane 3: dropped by the transpose
          }
          float* out = &blk.v[0][0][0];  // component j = 3 * vertex + axis at out + 4 * j
          for (int k = 0; k < 3; ++k) {
            _MM_TRANSPOSE4_PS(p[k][0], p[k][1], p[k][2], p[k][3]);
            for (int a = 0; a < 3; ++a) _mm_store_ps(out + 4 * (3 * k + a), p[k][a]);
          }
          out_blocks[b] = blk;
        }
      };
      if (parallel && block_count >= 2 * kFillChunk) {
        arena.execute([&] {
          tbb::parallel_for(tbb::blocked_range<uint32_t>(0, block_count, kFillChunk),
                            [&](const tbb::blocked_range<uint32_t>& r) { fill_range(r.begin(), r.end()); });
        });
      } else {
        fill_range(0, block_count);
      }
    };
    // The binary subtree of every node: its first triangle, triangle count and leaf count
    // (children always follow their parent in the node array, so one backward pass).
    const uint32_t max_leaf = static_cast<uint32_t>(std::clamp(options.max_leaf_size, 1, 1 << 20));
    const size_t nb = bin.size();
    // Uninitialised (every entry but the padding node's is written before it is read).
    const std::unique_ptr<uint32_t[]> sub_first(new uint32_t[nb]), sub_count(new uint32_t[nb]),
        sub_leaves(new uint32_t[nb]);
    for (size_t j = nb; j-- > 0;) {
      if (j == 1) continue;  // padding
      const BvhNode& c = bin[j];
      if (c.is_leaf()) {
        sub_first[j] = c.left_first, sub_count[j] = c.count, sub_leaves[j] = 1;
      } else {
        const uint32_t l = c.left_first, r = l + 1;
        sub_first[j] = sub_first[l];
        // Siblings hold adjacent triangle ranges (the builder partitions in place); a subtree
        // whose range were not contiguous could not become one leaf.
        const bool contiguous = sub_count[l] <= max_leaf && sub_count[r] <= max_leaf && sub_first[r] == sub_first[l] + sub_count[l];
        sub_count[j] = contiguous ? sub_count[l] + sub_count[r] : 0xFFFFFFFFu;
        sub_leaves[j] = sub_leaves[l] + sub_leaves[r];
      }
    }
    const auto collapse_into = [&](auto& wide) {
      using Node = typename std::remove_reference_t<decltype(wide)>::value_type;
      constexpr int W = Node::kWidth;
      // Leaves end the collapse, so wide nodes hold fewer than W children: the bunny gets one
      // wide node per 4.9 / 9.9 / 26.5 binary nodes at W = 4 / 8 / 16. Reserving for W - 1
      // regrew the array (copying every node) with the greedy collapse; this bound never does.
      wide.reserve(bin.size() / std::min(W - 1, 4) + 1);
      prepare_for_writes(wide.data(), wide.capacity() * sizeof(Node));
      // SAH-optimal collapse (Ylitie, Karras, Laine 2017, "Efficient Incoherent Ray Traversal on
      // GPUs Through Compressed Wide BVHs", section 3.1): cost[j][k - 1] is the least SAH cost
      // of the binary subtree j as at most k children of a wide node, each child a wide node
      // (cost: its area times kNodeCost, plus its own children) or a leaf (area times its
      // blocks of four triangles; any subtree of at most max_leaf triangles may become one
      // leaf). The greedy collapse (open the largest child until W) left 4.2 children per
      // 8-wide node and visited more nodes per ray.
      // Node and block costs equal, as the binary SAH charges them, for the kernels that test
      // one block per SIMD operation: dearer nodes (1.5, 2.5) merged leaves and tested more
      // triangles (avx2x8 diffuse rays +0.2%, +2.4% instructions). The 16-wide AVX-512 kernel
      // tests two blocks per operation and a node of 16 boxes: 2.5 merges small subtrees into
      // leaves there (bunny: 1,451 -> 1,026 nodes, 10.4 -> 13.0 children each), 2-6% faster
      // on most single-ray kinds in alternating wall-time runs (1, 2.5, 4, 6 tried).
      const float kNodeCost = W == 16 ? 2.5f : 1.0f;
      constexpr float kBlockCost = 1.0f;
      // (Four floats more: the DP below reads a row in groups of four, past its end.)
      float* const cost = static_cast<float*>(scratch->get(2, sizeof(float) * (nb * W + 4)));
      // split[j][k - 1]: 0 = as for k - 1 slots (or, for k = 1: 0 = wide node, 1 = leaf), else
      // the left child's slot count a (the right one gets k - a).
      auto* const split = static_cast<uint8_t*>(scratch->get(3, nb * W));
      // The best split of k slots (at most as many as subtree j has leaves: \p k is clamped)
      // between j's children: returns the left one's share, 0 when none beats \p best.
      const auto best_split = [&](uint32_t j, int& k, float& best) {
        const uint32_t l = bin[j].left_first, r = l + 1;
        k = std::min(k, static_cast<int>(std::min<uint32_t>(sub_leaves[j], W)));
        const int lo = std::max(1, k - static_cast<int>(std::min<uint32_t>(sub_leaves[r], W))),
                  hi = std::min(k - 1, static_cast<int>(std::min<uint32_t>(sub_leaves[l], W)));
        int arg = 0;
        for (int a = lo; a <= hi; ++a) {
          const float c = cost[size_t{l} * W + static_cast<size_t>(a - 1)] + cost[size_t{r} * W + static_cast<size_t>(k - a - 1)];
          if (c < best) best = c, arg = a;
        }
        return arg;
      };
      // One node of the programme, from its children's rows (which come later in the array).
      const auto dp = [&](size_t j) {
        const uint32_t jj = static_cast<uint32_t>(j);
        float* cj = &cost[j * W];
        uint8_t* sj = &split[j * W];
        const float area = std::max(half_area_of(jj), 0.0f);
        const float leaf = sub_count[j] <= max_leaf ? area * kBlockCost * blocks(sub_count[j]) : kInf;
        if (bin[j].is_leaf()) {
          // (Separate loops: the byte stores may alias the floats, which kept the compiler
          // from vectorising the fused loop.)
          for (int k = 0; k < W; ++k) cj[k] = leaf;
          sj[0] = 1;
          for (int k = 1; k < W; ++k) sj[k] = 0;
          return;
        }
        // best_split for every k at once: m[k - 1] is the least cost[l][a - 1] + cost[r][k - a - 1]
        // over the a best_split would try, arg[k - 1] the first a reaching it (a ascends and
        // only a strictly smaller cost replaces, as there), so the tables are unchanged. Row by
        // row over a the updates are branch-free; calling best_split per k (up to 120 compares
        // per node at W = 16, data-dependent branches) made this phase 1.9 ms of the bunny
        // build, now 1.4 ms.
        const uint32_t l = bin[j].left_first, r = l + 1;
        const int ll = static_cast<int>(std::min<uint32_t>(sub_leaves[l], W)),
                  lr = static_cast<int>(std::min<uint32_t>(sub_leaves[r], W));
        const float* const cl = &cost[size_t{l} * W];
        const float* const cr = &cost[size_t{r} * W];
        // Four t at a time (SSE2; lanes t >= tn masked off, so m and arg have three entries of
        // padding and cr may be read up to three floats past tn).
        alignas(16) float m[W + 4];
        alignas(16) int32_t arg[W + 4];
        for (int k = 0; k < W + 4; ++k) m[k] = kInf, arg[k] = 0;
        const __m128i lane = _mm_setr_epi32(0, 1, 2, 3);
        for (int a = 1; a <= std::min(ll, W - 1); ++a) {
          const __m128 ca = _mm_set1_ps(cl[a - 1]);
          const __m128i av = _mm_set1_epi32(a);
          const int tn = std::min(lr, W - a);
          float* const ma = m + a;
          int32_t* const aa = arg + a;
          for (int t = 0; t < tn; t += 4) {
            const __m128 c = _mm_add_ps(ca, _mm_loadu_ps(cr + t));
            const __m128 old = _mm_loadu_ps(ma + t);
            const __m128 lt = _mm_and_ps(_mm_cmplt_ps(c, old),
                                         _mm_castsi128_ps(_mm_cmpgt_epi32(_mm_set1_epi32(tn - t), lane)));
            _mm_storeu_ps(ma + t, _mm_or_ps(_mm_and_ps(lt, c), _mm_andnot_ps(lt, old)));
            const __m128i li = _mm_castps_si128(lt);
            const __m128i olda = _mm_loadu_si128(reinterpret_cast<const __m128i*>(aa + t));
            _mm_storeu_si128(reinterpret_cast<__m128i*>(aa + t),
                             _mm_or_si128(_mm_and_si128(li, av), _mm_andnot_si128(li, olda)));
          }
        }
        const int kmax = static_cast<int>(std::min<uint32_t>(sub_leaves[j], W));
        const float node = m[kmax - 1] + area * kNodeCost;
        cj[0] = std::min(leaf, node);
        // A leaf only within max_leaf: where both costs overflowed to inf (coordinates near the
        // float range's end; the sums over a big subtree exceed it), inf <= inf chose a leaf of
        // the whole subtree. Finite costs decide as before (leaf is kInf beyond max_leaf).
        sj[0] = sub_count[j] <= max_leaf && leaf <= node ? 1 : 0;
        // The running best in a register: read back from cj, it waited on the store just made
        // (store forwarding every step; the byte stores to sj may alias cj, so the compiler
        // could not keep it).
        float best = cj[0];
        for (int k = 2; k <= W; ++k) {
          const bool better = k <= kmax && m[k - 1] < best;
          best = better ? m[k - 1] : best;
          cj[k - 1] = best;
          sj[k - 1] = static_cast<uint8_t>(better ? arg[k - 1] : 0);
        }
      };
      // Children follow their parents, and a node's descendants are one contiguous range after
      // its sibling pair ([left child, left child + 2 * (leaves - 1)), the depth-first pair
      // layout), so with threads the subtrees below a cut of at most nb / 64 nodes each are
      // tasks, and the few nodes above the cut follow in decreasing order. Every row depends
      // only on the children's: the same tables in any order.
      if (parallel && nb >= kParallelDpMin) {
        const uint64_t cut = nb / 64;
        std::vector<uint32_t> cuts, upper, todo{0};
        while (!todo.empty()) {
          const uint32_t j = todo.back();
          todo.pop_back();
          if (bin[j].is_leaf() || 2 * uint64_t{sub_leaves[j]} - 1 <= cut) {
            cuts.push_back(j);
          } else {
            upper.push_back(j);
            todo.push_back(bin[j].left_first);
            todo.push_back(bin[j].left_first + 1);
          }
        }
        arena.execute([&] {
          tbb::parallel_for(tbb::blocked_range<size_t>(0, cuts.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
            for (size_t c = r.begin(); c != r.end(); ++c) {
              const uint32_t j = cuts[c];
              if (!bin[j].is_leaf()) {
                const size_t l = bin[j].left_first, descendants = 2 * size_t{sub_leaves[j]} - 2;
                for (size_t i = l + descendants; i-- > l;) dp(i);
              }
              dp(j);
            }
          });
        });
        std::sort(upper.begin(), upper.end(), std::greater<>());
        for (const uint32_t j : upper) dp(j);
      } else {
        for (size_t j = nb; j-- > 0;)
          if (j != 1) dp(j);
      }
      // The children (binary node, as a leaf?) of the wide node made of subtree j with k slots.
      struct Slot {
        uint32_t node;
        bool leaf;
      };
      const auto gather = [&](const auto& self, uint32_t j, int k, Slot* out, int& used) -> void {
        while (k > 1 && split[size_t{j} * W + static_cast<size_t>(k - 1)] == 0) --k;
        if (k == 1) {
          out[used++] = {j, split[size_t{j} * W] == 1};
          return;
        }
        const int a = split[size_t{j} * W + static_cast<size_t>(k - 1)];
        self(self, bin[j].left_first, a, out, used);
        self(self, bin[j].left_first + 1, k - a, out, used);
      };
      const auto collapse = [&](const auto& self, uint32_t b) -> uint32_t {
        Slot list[W];
        int k = 0;
        if (bin[b].is_leaf()) {
          list[k++] = {b, true};
        } else {
          float best = kInf;  // the best split of (at most) W slots below the node itself
          int slots = W;
          int a = best_split(b, slots, best);
          // No split has a finite cost (every one overflowed to inf, or is NaN from an infinite
          // extent times a flat one): any split is valid, and a = 0 would hand gather() zero
          // slots, which it cannot split (it read split[-1] and recursed until the stack ran
          // out). One slot left, the rest right (slots >= 2: b is not a leaf).
          if (a == 0) a = 1;
          gather(gather, bin[b].left_first, a, list, k);
          gather(gather, bin[b].left_first + 1, slots - a, list, k);
          // Largest child first: any-hit walks visit the children in slot order, and a larger
          // box is likelier to hold an occluder (closest-hit walks order by distance).
          // (Insertion sort: at most W entries, no allocation as std::stable_sort makes.)
          float area[W];
          for (int i = 0; i < k; ++i) area[i] = half_area_of(list[i].node);
          for (int i = 1; i < k; ++i) {
            const Slot x = list[i];
            const float ax = area[i];
            int j = i;
            for (; j > 0 && area[j - 1] < ax; --j) list[j] = list[j - 1], area[j] = area[j - 1];
            list[j] = x, area[j] = ax;
          }
        }
        const uint32_t index = static_cast<uint32_t>(wide.size());
        wide.emplace_back();  // the slot; filled after the subtrees (pre-order numbering)
        Node w;
        for (int i = 0; i < W; ++i) {
          if (i >= k) {
            for (int a = 0; a < 3; ++a) w.b[0][a][i] = kInf, w.b[1][a][i] = -kInf;
            w.child[i] = 0;
            w.count[i] = 0;
            continue;
          }
          const uint32_t j = list[i].node;
          const BvhNode& c = bin[j];
          for (int a = 0; a < 3; ++a) w.b[0][a][i] = c.min[a], w.b[1][a][i] = c.max[a];
          w.count[i] = list[i].leaf ? sub_count[j] : 0;
          w.child[i] = list[i].leaf ? make_blocks(sub_first[j], sub_count[j]) : self(self, j);
        }
        wide[index] = w;
        return index;
      };
      collapse(collapse, 0);
    };
    if (bvh.kernel_ == BvhKernel::Avx512x16) {
      collapse_into(bvh.wide16_);
    } else if (bvh_kernel_is_8_wide(bvh.kernel_)) {
      collapse_into(bvh.wide8_);
    } else {
      collapse_into(bvh.wide_);
    }
    fill_blocks();
  }

  // 5. Figures: node/leaf counts and depth in one pass over the node array (parents come
  //    before their children; the array is the same for any thread count, so the sums are
  //    too; a depth-first walk with a stack cost 2-3% of the bunny build), and the SAH cost.
  BuildInfo& bi = bvh.info_;
  const size_t m = bvh.prim_ids_.size();
  bi.nodes = m == 0 ? 1 : bvh.nodes_.size() - 1;  // minus the padding node
  size_t leaves = 0;
  uint32_t max_depth = 0;
  {
    // The references' scratch is free now and holds at least 8 bytes per node.
    uint32_t* const depth = static_cast<uint32_t*>(scratch->get(0, sizeof(uint32_t) * bvh.nodes_.size()));
    depth[0] = 0;
    for (size_t j = 0; j < bvh.nodes_.size(); ++j) {
      if (j == 1) continue;  // padding
      const BvhNode& nd = bvh.nodes_[j];
      max_depth = std::max(max_depth, depth[j]);
      if (nd.is_leaf() || m == 0) {
        ++leaves;
      } else {
        depth[nd.left_first] = depth[nd.left_first + 1] = depth[j] + 1;
      }
    }
  }
  bi.max_depth = max_depth;
  bi.leaves = leaves;
  bi.sah_cost = m > 0 ? binary_sah_cost(bvh.nodes_, options.traversal_cost) : 0.0;
  bi.bytes = bvh.memory_bytes();
  bi.build_ms = timer.ms();
  if (info) *info = bi;
  return bvh;
}

struct Bvh::TriangleCache {
  std::once_flag once;
  std::vector<BvhTriangle, detail::AlignedAllocator<BvhTriangle>> tris;
};

std::span<const BvhTriangle> Bvh::triangles() const {
  if (prim_ids_.empty()) return {};
  TriangleCache& c = *tris_;
  std::call_once(c.once, [&] {
    // Every triangle sits in exactly one block lane (its scene index); prim_ids_ says where
    // it goes in BVH order.
    uint32_t max_id = 0;
    for (const uint32_t id : prim_ids_) max_id = std::max(max_id, id);
    std::vector<uint32_t> order(size_t{max_id} + 1);
    for (size_t i = 0; i < prim_ids_.size(); ++i) order[prim_ids_[i]] = static_cast<uint32_t>(i);
    c.tris.reserve(prim_ids_.size());
    prepare_for_writes(c.tris.data(), prim_ids_.size() * sizeof(BvhTriangle));
    c.tris.resize(prim_ids_.size());
    for (const BvhTriangle4& blk : tri4_)
      for (int lane = 0; lane < 4; ++lane) {
        if (blk.index[lane] == kNoHit) continue;
        BvhTriangle& t = c.tris[order[blk.index[lane]]];
        for (int k = 0; k < 9; ++k) t.v[k] = blk.v[k / 3][k % 3][lane];
      }
  });
  return c.tris;
}

Aabb Bvh::bounds() const {
  Aabb b;
  if (!prim_ids_.empty()) {
    b.min = nodes_[0].min;
    b.max = nodes_[0].max;
  }
  return b;
}

size_t Bvh::memory_bytes() const {
  return nodes_.size() * sizeof(BvhNode) + wide_.size() * sizeof(BvhWideNode) + wide8_.size() * sizeof(BvhWideNode8) + wide16_.size() * sizeof(BvhWideNode16) +
         tri4_.size() * sizeof(BvhTriangle4) +
         prim_ids_.size() * sizeof(uint32_t) + transmittance_.size() * sizeof(Vec3);
}

}  // namespace specula
