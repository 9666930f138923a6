/// \file bvh.h
/// Bounding volume hierarchy over triangles: binned-SAH build of a binary tree (multi-threaded
/// with TBB, flat 32-byte nodes), collapsed into the 4-, 8- or 16-wide node layout of the
/// traversal kernel (BvhKernel), leaves as blocks of four triangles for the watertight test.
///
/// Layout follows Bikker's lecture (seed 004): a node is {min, leftFirst, max, count}; an interior
/// node has count == 0 and its children at leftFirst and leftFirst + 1 (siblings share one
/// 64-byte cache line); a leaf has count > 0 triangles starting at leftFirst in BVH order. Node 0
/// is the root, node 1 is unused padding so that every sibling pair is cache-line aligned.
///
/// Most code should go through build_tracer() (accel.h); this header is for tools and tests
/// that want to look at the tree itself.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <span>
#include <utility>
#include <vector>

#include "specula/accel.h"
#include "specula/math.h"
#include "specula/tracer.h"

namespace specula {

/// One 32-byte BVH node (seed 004).
struct alignas(32) BvhNode {
  Vec3 min;
  uint32_t left_first = 0;  ///< interior: index of the left child (right = +1); leaf: first triangle
  Vec3 max;
  uint32_t count = 0;  ///< triangles in a leaf; 0 for interior nodes

  bool is_leaf() const { return count > 0; }
};
static_assert(sizeof(BvhNode) == 32, "BVH nodes must stay 32 bytes");

/// A triangle as the traversal stores it: the three vertices, BVH order. The watertight test
/// needs the untransformed vertices (precomputed edges would break watertightness).
struct BvhTriangle {
  float v[9];  ///< v0.xyz, v1.xyz, v2.xyz

  Vec3 vertex(int i) const { return {v[3 * i], v[3 * i + 1], v[3 * i + 2]}; }
};

/// Four triangles of one leaf in structure-of-arrays form for the SSE watertight test:
/// v[vertex][axis][lane]. A leaf of n triangles owns ceil(n / 4) consecutive blocks; the lanes
/// past its last triangle are padding (NaN vertices, never hit; index kNoHit).
struct alignas(16) BvhTriangle4 {
  float v[3][3][4];
  uint32_t index[4];  ///< scene (input) triangle index of each lane, as Hit::prim; kNoHit = padding
};
static_assert(sizeof(BvhTriangle4) == 160, "triangle blocks are 2.5 cache lines");

/// Traversal layout derived from the binary tree after the build (Wald et al. 2008, "Getting
/// Rid of Packets": multi-branching BVH for single rays): every node holds up to W children
/// (the binary tree collapsed by a dynamic programme that picks each node's children for the
/// least SAH cost, Ylitie et al. 2017; children in decreasing area),
/// bounds stored as SIMD lanes so one slab test (SSE for W = 4, AVX2 for W = 8) covers all of
/// them. b[0] = min, b[1] = max, each [axis][child]. Empty slots have min = +inf, max = -inf,
/// which the near/far-plane slab test always rejects.
template <int W>
struct alignas(64) BvhNodeW {
  static constexpr int kWidth = W;
  float b[2][3][W];
  uint32_t child[W];  ///< interior: index of a node of the same width; leaf: first block in triangle_blocks()
  uint32_t count[W];  ///< triangles of a leaf child (in ceil(count / 4) blocks); 0 for an interior child
};
using BvhWideNode = BvhNodeW<4>;   ///< BvhKernel::Sse4
using BvhWideNode8 = BvhNodeW<8>;  ///< BvhKernel::Avx2x8 and Avx512x8
using BvhWideNode16 = BvhNodeW<16>;  ///< BvhKernel::Avx512x16
static_assert(sizeof(BvhWideNode) == 128, "4-wide nodes are two cache lines");
static_assert(sizeof(BvhWideNode8) == 256, "8-wide nodes are four cache lines");
static_assert(sizeof(BvhWideNode16) == 512, "16-wide nodes are eight cache lines");

namespace detail {
/// Minimal allocator for cache-line aligned arrays (nodes, triangles).
template <class T, size_t Align = 64>
struct AlignedAllocator {
  using value_type = T;
  AlignedAllocator() = default;
  template <class U>
  AlignedAllocator(const AlignedAllocator<U, Align>&) noexcept {}
  template <class U>
  struct rebind {
    using other = AlignedAllocator<U, Align>;
  };
  T* allocate(size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), std::align_val_t{Align})); }
  /// Default-initialises: resize() and emplace_back() without arguments leave trivial elements
  /// unwritten. Every user writes each element afterwards (the BVH build's nodes and blocks, the
  /// latter from several threads; the brute-force tracer's blocks; Bvh::triangles()).
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    if constexpr (sizeof...(Args) == 0)
      ::new (static_cast<void*>(p)) U;
    else
      ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
  void deallocate(T* p, size_t) noexcept { ::operator delete(p, std::align_val_t{Align}); }
  template <class U>
  bool operator==(const AlignedAllocator<U, Align>&) const noexcept { return true; }
};
}  // namespace detail

/// The SAH cost of a binary tree in Bvh::nodes()' layout, as BuildInfo::sah_cost reports it:
/// node half areas times \p traversal_cost (1 unless that is finite and >= 0), leaves' times their
/// triangles, over the root's; a flat root gives the triangle count. Node 0 is the root, node 1
/// is skipped (padding); the other nodes may come in any order, only their boxes and counts
/// are read.
double binary_sah_cost(std::span<const BvhNode> nodes, float traversal_cost);

/// The BVH. Immutable after build; all queries are const and safe to call from many threads.
class Bvh final : public Tracer {
 public:
  /// Binned-SAH build over \p input (see BvhOptions). Throws specula::Error on invalid input.
  /// Fills \p info (build time, node/leaf counts, depth, SAH cost, bytes) when non-null.
  static Bvh build(const TriangleInput& input, const BvhOptions& options = {}, BuildInfo* info = nullptr);

  Bvh() = default;

  std::string name() const override { return "bvh"; }
  void intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats = nullptr) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override;

  /// Single-ray conveniences (same results as the batched calls).
  Hit intersect(const Ray& ray) const;
  bool occluded(const Ray& ray) const;  ///< any triangle crossed in (tmin, tmax), transparent or not

  std::span<const BvhNode> nodes() const { return nodes_; }
  /// The kernel the queries use (never Auto): which of the wide layouts below is filled.
  BvhKernel kernel() const { return kernel_; }
  /// Whether batches trace coherent groups of rays as packets (BvhOptions::packets).
  bool packets() const { return packets_; }
  /// The 4-wide traversal layout derived from nodes() (BvhKernel::Sse4; empty otherwise).
  std::span<const BvhWideNode> wide_nodes() const { return wide_; }
  /// The 8-wide traversal layout derived from nodes() (8-wide kernels; empty otherwise).
  std::span<const BvhWideNode8> wide8_nodes() const { return wide8_; }
  /// The 16-wide traversal layout derived from nodes() (BvhKernel::Avx512x16; empty otherwise).
  std::span<const BvhWideNode16> wide16_nodes() const { return wide16_; }
  /// The triangles in BVH order (prim_ids() order). The traversal never reads them: they are
  /// copied out of triangle_blocks() on the first call (thread-safe) instead of by every build.
  std::span<const BvhTriangle> triangles() const;
  /// The leaves' triangles in blocks of four (what the leaf tests actually read).
  std::span<const BvhTriangle4> triangle_blocks() const { return tri4_; }
  /// BVH order -> scene triangle index.
  std::span<const uint32_t> prim_ids() const { return prim_ids_; }
  const BuildInfo& build_info() const { return info_; }
  Aabb bounds() const;

 private:
  std::vector<BvhNode, detail::AlignedAllocator<BvhNode>> nodes_;
  std::vector<BvhWideNode, detail::AlignedAllocator<BvhWideNode>> wide_;
  std::vector<BvhWideNode8, detail::AlignedAllocator<BvhWideNode8>> wide8_;
  std::vector<BvhWideNode16, detail::AlignedAllocator<BvhWideNode16>> wide16_;
  BvhKernel kernel_ = BvhKernel::Sse4;
  bool packets_ = true;
  struct TriangleCache;  ///< triangles(), filled on first use; shared by copies (immutable)
  std::shared_ptr<TriangleCache> tris_;
  std::vector<BvhTriangle4, detail::AlignedAllocator<BvhTriangle4>> tri4_;
  std::vector<uint32_t> prim_ids_;
  std::vector<Vec3> transmittance_;  ///< scene (input) order; empty when every triangle is opaque
  BuildInfo info_;

  friend class BvhBuilder;
  friend class BvhTraversal;
};

}  // namespace specula
