// BVH traversal: closest hit and transmittance/any-hit (owner: accel).
//
// Stack-based traversal (seed 004; seed 002, section 3.3.4) of the wide layout derived from the
// binary tree (BvhNodeW): one slab test covers all children of a node, 4 with SSE
// (BvhKernel::Sse4, the x86-64 baseline), 8 with AVX2 (Avx2x8, and Avx512x8: the same code with
// AVX-512VL's 32 registers) or 16 with AVX-512 (Avx512x16); hit children are visited nearest
// first, the others pushed with their entry distance, and popped subtrees farther than the
// current closest hit are skipped. Wider nodes mean fewer dependent node fetches and
// unpredictable branches per ray (bunny bounce rays: binary 25, 4-wide 14, 8-wide 9, 16-wide
// 7.6 node visits). The kernels are one source (bvh_kernel.inc) compiled once per kernel with
// its target attribute, chosen per BVH at build time (CPUID), so one binary runs on every
// x86-64 and uses AVX2 / AVX-512 where the CPU has them.
//
// Ray/box: slab test with a precomputed reciprocal direction; near and far planes are chosen
// once per ray from the direction signs. There is no separate test of the root box: the root
// wide node's slab test culls the rays that miss the tree. A zero direction component has an infinite reciprocal;
// when the origin lies exactly in that slab's plane, (bound - org) * rcp is 0 * inf = NaN, and
// for such rays (only) the min/max chains are ordered so that a NaN slab is ignored (SSE/AVX
// min/max return their second operand when either is NaN): a ray running inside a box's face
// plane is inside that slab, as the closed box and the edge-inclusive triangle test need. Other
// rays take a shallower min/max tree. The far distance is scaled by
// 1 + 2 gamma(3) as in Ize 2013, "Robust BVH Ray Traversal" (JCGT 2(2)), so that rounding can
// never make a ray miss a box that contains a triangle it hits (flat boxes of axis-aligned
// triangles in particular). Triangles use the watertight test (watertight.h).
//
// Leaves are tested four triangles at a time (BvhTriangle4 blocks, SSE intersect_watertight4:
// bit-identical to the scalar test; a block where some edge function is exactly zero goes to
// the scalar test with its double-precision fallback), two blocks per AVX operation in the
// AVX-512 kernels (the same operations lane by lane), so every kernel reports bit-identical
// hits. Child ordering follows Embree's wide single-ray traversal: one hit child is taken
// directly, two with one compare, more are pushed and insertion-sorted on the stack top;
// pushed subtrees are prefetched.
//
// Packets (bvh_packet.inc, included into every kernel): groups of 32 consecutive coherent rays
// of a batch go through the tree together with a frustum test per node, seed 004's early-in
// (the first active ray's slab test) and exact per-ray tests where a ray mask is needed; they
// hand subtrees that few rays enter to the single-ray walks above (closest_walk, transmit_walk),
// so every ray sees exactly the triangles the single-ray kernel would test it against.
#include <emmintrin.h>  // SSE2: x86-64 baseline
#include <immintrin.h>  // AVX2 kernel: compiled per function (target attribute), chosen at run time
#include <xmmintrin.h>  // _mm_prefetch

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>

#include "accel/triangles.h"
#include "accel/watertight.h"
#include "specula/bvh.h"
#include "specula/error.h"

namespace specula {

namespace {

/// 1 + 2 * gamma(3), gamma(n) = n eps / (1 - n eps), eps = 2^-24 (Ize 2013).
constexpr float kFarScale = 1.0f + 2.0f * (3.0f * 0x1p-24f) / (1.0f - 3.0f * 0x1p-24f);

/// A Ray as two SSE registers: (org, tmin) and (dir, tmax) (the struct's layout, checked below).
static_assert(sizeof(Ray) == 32 && offsetof(Ray, tmin) == 12 && offsetof(Ray, dir) == 16 && offsetof(Ray, tmax) == 28,
              "Ray must be org, tmin, dir, tmax: the kernels load it as two SSE registers");
SPECULA_ACCEL_INLINE __m128 load_org_tmin(const Ray& ray) { return _mm_loadu_ps(&ray.org.x); }
SPECULA_ACCEL_INLINE __m128 load_dir_tmax(const Ray& ray) { return _mm_loadu_ps(&ray.dir.x); }
/// Lanes 0..2 of \p a that are finite (|a| < inf; NaN is not).
SPECULA_ACCEL_INLINE int finite_xyz(__m128 a) {
  const __m128 abs = _mm_and_ps(a, _mm_castsi128_ps(_mm_set1_epi32(0x7FFFFFFF)));
  return _mm_movemask_ps(_mm_cmplt_ps(abs, _mm_set1_ps(kInf))) & 7;
}

/// Per-ray constants of the box test (the kernels broadcast them to their SIMD width).
/// The three reciprocals are one SSE division (the same IEEE quotients as three scalar ones).
struct BoxRay {
  float sox, soy, soz, srx, sry, srz;  ///< origin and reciprocal direction
  unsigned signs;  ///< bit a: !(reciprocal a >= 0), the slab test's near plane of axis a is the max
  bool zero_component;  ///< some direction component is +-0 (or denormal): rcp infinite

  explicit SPECULA_ACCEL_INLINE BoxRay(const Ray& ray) {
    sox = ray.org.x, soy = ray.org.y, soz = ray.org.z;
    const __m128 rcp = _mm_div_ps(_mm_set1_ps(1.0f), load_dir_tmax(ray));  // +-inf for +-0; lane 3 unused
    alignas(16) float r[4];
    _mm_store_ps(r, rcp);
    srx = r[0], sry = r[1], srz = r[2];
    signs = static_cast<unsigned>(_mm_movemask_ps(_mm_cmpnge_ps(rcp, _mm_setzero_ps()))) & 7u;
    zero_component = finite_xyz(rcp) != 7;
  }
};

/// Rays the traversal can answer at all: finite origin and direction, non-zero direction,
/// tmin <= tmax. Everything else misses (and is fully transmitted), without touching the tree.
/// (One SSE compare per condition instead of six scalar finiteness tests with branches.)
SPECULA_ACCEL_INLINE bool valid_ray(const Ray& ray) {
  const __m128 o = load_org_tmin(ray), d = load_dir_tmax(ray);
  const bool finite = (finite_xyz(o) & finite_xyz(d)) == 7;
  const bool nonzero = (_mm_movemask_ps(_mm_cmpneq_ps(d, _mm_setzero_ps())) & 7) != 0;  // NaN excluded above
  return finite && nonzero && ray.tmin <= ray.tmax;
}

/// One pending subtree: a wide node (count == 0) or a leaf's triangle range, with its entry t.
struct WideEntry {
  uint32_t child;
  uint32_t count;
  float t;
};

/// Deepest binary tree the builder makes (its kMedianDepth + 32). A wide tree is never deeper,
/// and a kernel pushes at most W - 1 siblings per wide level.
constexpr int kMaxBinaryDepth = 64 + 32;

/// What the kernels read of a Bvh.
struct BvhView {
  const BvhNode* root;
  const void* wide;  ///< BvhNodeW<W> of the kernel
  const BvhTriangle4* blocks;  ///< the leaves' triangles (lanes carry scene indices)
  const Vec3* trans;  ///< per scene triangle; null when all are opaque
  bool empty;
  bool packets;  ///< trace coherent groups of consecutive rays as packets (BvhOptions::packets)
};

}  // namespace

// The kernels: one source, compiled per node width and instruction set.
#define SPECULA_KERNEL_NS sse4
#define SPECULA_KERNEL_PAIRS 0
#define SPECULA_KERNEL_WIDTH 4
#define SPECULA_KERNEL_TARGET
#include "accel/bvh_kernel.inc"
#undef SPECULA_KERNEL_NS
#undef SPECULA_KERNEL_WIDTH
#undef SPECULA_KERNEL_TARGET
#undef SPECULA_KERNEL_PAIRS

#define SPECULA_KERNEL_NS avx2x8
#define SPECULA_KERNEL_PAIRS 0
#define SPECULA_KERNEL_WIDTH 8
#define SPECULA_KERNEL_TARGET __attribute__((target("avx2")))
#include "accel/bvh_kernel.inc"
#undef SPECULA_KERNEL_NS
#undef SPECULA_KERNEL_WIDTH
#undef SPECULA_KERNEL_TARGET
#undef SPECULA_KERNEL_PAIRS

// The 8-wide kernel again for AVX-512VL: the same 256-bit operations, but 32 vector registers,
// so the per-ray constants of the slab and triangle tests are never spilled to the stack.
#define SPECULA_KERNEL_NS avx512x8
#define SPECULA_KERNEL_PAIRS 1
#define SPECULA_KERNEL_WIDTH 8
#define SPECULA_KERNEL_TARGET __attribute__((target("avx2,avx512f,avx512vl")))
#include "accel/bvh_kernel.inc"
#undef SPECULA_KERNEL_NS
#undef SPECULA_KERNEL_WIDTH
#undef SPECULA_KERNEL_TARGET
#undef SPECULA_KERNEL_PAIRS

#define SPECULA_KERNEL_NS avx512x16
#define SPECULA_KERNEL_PAIRS 1
#define SPECULA_KERNEL_WIDTH 16
#define SPECULA_KERNEL_TARGET __attribute__((target("avx2,avx512f,avx512vl")))
#include "accel/bvh_kernel.inc"
#undef SPECULA_KERNEL_NS
#undef SPECULA_KERNEL_WIDTH
#undef SPECULA_KERNEL_TARGET
#undef SPECULA_KERNEL_PAIRS

int bvh_packet_rays(BvhKernel kernel) {
  switch (resolve_bvh_kernel(kernel)) {
    case BvhKernel::Avx512x16: return avx512x16::P;
    case BvhKernel::Avx512x8: return avx512x8::P;
    case BvhKernel::Avx2x8: return avx2x8::P;
    default: return sse4::P;
  }
}

class BvhTraversal {
 public:
  static BvhView view(const Bvh& bvh) {
    const bool eight = bvh_kernel_is_8_wide(bvh.kernel_);
    const bool sixteen = bvh.kernel_ == BvhKernel::Avx512x16;
    return BvhView{bvh.nodes_.data(),
                   sixteen ? static_cast<const void*>(bvh.wide16_.data())
                   : eight ? static_cast<const void*>(bvh.wide8_.data())
                           : static_cast<const void*>(bvh.wide_.data()),
                   bvh.tri4_.data(),
                   bvh.transmittance_.empty() ? nullptr : bvh.transmittance_.data(),
                   bvh.prim_ids_.empty(),
                   bvh.packets_};
  }

  template <bool kStats>
  static void intersect_with(BvhKernel kernel, const BvhView& v, std::span<const Ray> rays, std::span<Hit> hits,
                             TraceStats& st) {
    switch (kernel) {
      case BvhKernel::Avx512x16: return avx512x16::intersect_batch<kStats>(v, rays, hits, st);
      case BvhKernel::Avx512x8: return avx512x8::intersect_batch<kStats>(v, rays, hits, st);
      case BvhKernel::Avx2x8: return avx2x8::intersect_batch<kStats>(v, rays, hits, st);
      default: return sse4::intersect_batch<kStats>(v, rays, hits, st);
    }
  }

  template <bool kStats, bool kAnyHit>
  static void transmit_with(BvhKernel kernel, const BvhView& v, std::span<const Ray> rays, std::span<Vec3> out,
                            TraceStats& st) {
    switch (kernel) {
      case BvhKernel::Avx512x16: return avx512x16::transmit_batch<kStats, kAnyHit>(v, rays, out, st);
      case BvhKernel::Avx512x8: return avx512x8::transmit_batch<kStats, kAnyHit>(v, rays, out, st);
      case BvhKernel::Avx2x8: return avx2x8::transmit_batch<kStats, kAnyHit>(v, rays, out, st);
      default: return sse4::transmit_batch<kStats, kAnyHit>(v, rays, out, st);
    }
  }

  static void intersect(const Bvh& bvh, std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) {
    const BvhView v = view(bvh);
    TraceStats local;
    if (stats) {
      intersect_with<true>(bvh.kernel_, v, rays, hits, local);
      *stats += local;
    } else {
      intersect_with<false>(bvh.kernel_, v, rays, hits, local);
    }
  }

  template <bool kAnyHit>
  static void transmit(const Bvh& bvh, std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) {
    const BvhView v = view(bvh);
    TraceStats local;
    if (stats) {
      transmit_with<true, kAnyHit>(bvh.kernel_, v, rays, out, local);
      *stats += local;
    } else {
      transmit_with<false, kAnyHit>(bvh.kernel_, v, rays, out, local);
    }
  }
};

void Bvh::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  if (hits.size() < rays.size()) throw Error("Bvh::intersect: hits span smaller than rays span");
  BvhTraversal::intersect(*this, rays, hits, stats);
}

void Bvh::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("Bvh::transmittance: out span smaller than rays span");
  // All opaque: a pure occlusion query.
  if (transmittance_.empty()) {
    BvhTraversal::transmit<true>(*this, rays, out, stats);
  } else {
    BvhTraversal::transmit<false>(*this, rays, out, stats);
  }
}

Hit Bvh::intersect(const Ray& ray) const {
  Hit hit;
  BvhTraversal::intersect(*this, std::span<const Ray>(&ray, 1), std::span<Hit>(&hit, 1), nullptr);
  return hit;
}

bool Bvh::occluded(const Ray& ray) const {
  Vec3 tr;
  BvhTraversal::transmit<true>(*this, std::span<const Ray>(&ray, 1), std::span<Vec3>(&tr, 1), nullptr);
  return tr.x == 0.0f;
}

}  // namespace specula
