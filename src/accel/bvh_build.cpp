// Binned-SAH BVH construction (owner: accel).
//
// Algorithm: top-down binned SAH as in Wald 2007, "On fast Construction of SAH-based Bounding
// Volume Hierarchies", and Bikker's lecture (seed 004). Every node bins its primitives' centroids
// into BvhOptions::bins equal intervals of the centroid bounds on each axis, sweeps the bins to
// evaluate SAH costs of the bins - 1 candidate planes per axis, and splits at the cheapest plane
// unless making a leaf is cheaper (SAH termination) and the node holds at most max_leaf_size
// triangles. Primitive references (bounds + index, 32 bytes) are partitioned in place, so every
// pass over a node's primitives is a linear walk through memory. Child bounds come for free from
// the winning bin sweep; child centroid bounds are accumulated during the partition.
// The SAH charges leaves per block of four triangles (the traversal tests a BvhTriangle4 block
// at the price of about one triangle), so nodes of up to four triangles become leaves at once.
//
// Subtrees above a size threshold are built as TBB tasks; node pairs are allocated with an
// atomic counter and renumbered depth-first afterwards, so the result (nodes, triangle order)
// is identical for any thread count.
#include <emmintrin.h>  // SSE2: part of the x86-64 baseline, no -march needed

#include <algorithm>
#include <atomic>
#include <functional>
#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/info.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include "accel/triangles.h"
#include "accel/watertight.h"
#include "specula/bvh.h"
#include "specula/error.h"
#include "specula/timer.h"

namespace specula {

namespace {

/// A primitive reference: triangle bounds; lo[3] holds the triangle index (as bits).
/// Twice the centroid is lo + hi (we bin 2c to save a multiply; only ratios matter).
struct alignas(16) PrimRef {
  float lo[4];
  float hi[4];

  uint32_t id() const {
    uint32_t i;
    static_assert(sizeof(i) == sizeof(lo[3]));
    __builtin_memcpy(&i, &lo[3], sizeof(i));
    return i;
  }
};

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

/// Half surface area of a non-empty box, all in registers (the sweeps call this ~2 x bins x 3
/// times per node, which is most of the build time on small nodes).
inline float half_area4(__m128 lo, __m128 hi) {
  const __m128 e = _mm_sub_ps(hi, lo);
  const __m128 p = _mm_mul_ps(e, _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1)));  // ex*ey, ey*ez, ez*ex
  const __m128 s = _mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1)));
  return _mm_cvtss_f32(_mm_add_ss(s, _mm_movehl_ps(p, p)));
}

struct Bin {
  RawBox box;
  uint32_t count;
};

constexpr int kMaxBins = 256;
/// Leaves are tested four triangles at a time (BvhTriangle4), so the SAH charges a leaf by its
/// blocks of four, as Embree's BVH4/Triangle4 builder does: splitting four triangles or fewer
/// can never pay off, and leaves fill up to whole blocks.
constexpr uint32_t kBlock = 4;
inline float blocks(uint32_t n) { return static_cast<float>((n + kBlock - 1) / kBlock); }
/// Subtrees with more primitives than this are spawned as TBB tasks.
constexpr uint32_t kTaskThreshold = 4096;
/// Beyond this depth the builder stops using SAH and halves index ranges, which bounds the
/// depth (and so the traversal stack) at kMedianDepth + 32 whatever the input.
constexpr uint32_t kMedianDepth = 64;

struct Split {
  int axis = -1;
  int bin = 0;  ///< primitives with bin index < bin go left
  float cost = kInf;  ///< left_area * left_blocks + right_area * right_blocks (half areas)
  Box4 left, right;
  uint32_t left_count = 0;
  float bin_min = 0.0f, bin_scale = 0.0f;  ///< binning parameters of the chosen axis
  int bin_count = 0;
};

}  // namespace

class BvhBuilder {
 public:
  BvhBuilder(const BvhOptions& options, std::unique_ptr<PrimRef[]>& refs, BvhNode* nodes)
      : refs_(refs.get()), nodes_(nodes), bins_(std::clamp(options.bins, 2, kMaxBins)),
        max_leaf_(static_cast<uint32_t>(std::clamp(options.max_leaf_size, 1, 1 << 20))),
        traversal_cost_(std::isfinite(options.traversal_cost) && options.traversal_cost >= 0.0f
                            ? options.traversal_cost
                            : 1.0f) {}

  uint32_t node_count() const { return next_node_.load(); }

  /// Builds the whole tree over refs[0, count); node 0 is the root.
  void build_root(uint32_t count, const Box4& bounds, const Box4& cbounds, bool parallel) {
    next_node_ = 2;  // node 1 is padding: keeps sibling pairs on one cache line
    if (parallel) {
      tbb::task_group tg;
      build(0, 0, count, bounds, cbounds, 0, &tg);
      tg.wait();
    } else {
      build(0, 0, count, bounds, cbounds, 0, nullptr);
    }
  }

 private:
  static void make_leaf(BvhNode& node, uint32_t first, uint32_t count) {
    node.left_first = first;
    node.count = count;
  }

  static void store_box(BvhNode& node, const Box4& b) {
    const Aabb a = b.aabb();
    node.min = a.min;
    node.max = a.max;
  }

  /// Bins [first, first + count) on every axis with non-zero centroid extent and returns the
  /// cheapest split (axis -1 when all centroids coincide).
  Split find_split(uint32_t first, uint32_t count, const Box4& cbounds) const {
    alignas(16) float cmin[4], cext[4], scale[4];
    _mm_store_ps(cmin, cbounds.lo);
    _mm_store_ps(cext, _mm_sub_ps(cbounds.hi, cbounds.lo));
    // Small nodes need fewer bins (n + 1 candidate planes cannot beat n - 1 well-placed ones
    // by much) and the sweeps dominate the build time there.
    const int nb = std::min(bins_, std::max(4, static_cast<int>(count)));
    const float fbins = static_cast<float>(nb);
    for (int a = 0; a < 3; ++a) scale[a] = cext[a] > 0.0f ? fbins / cext[a] : 0.0f;
    scale[3] = 0.0f;
    const __m128 vmin = cbounds.lo, vscale = _mm_load_ps(scale);
    const __m128 vmaxbin = _mm_set1_ps(fbins - 1.0f);

    // Packed per node (axis a's bins at a * nb): a few cache lines instead of 3 x 256 bins
    // spaced 3 x 4 KiB apart, whose equal low address bits made loads of one axis wait on
    // stores of another (4K aliasing).
    Bin bin_store[3 * kMaxBins];
    Bin* bins[3] = {bin_store, bin_store + nb, bin_store + 2 * nb};
    const __m128 empty_lo = _mm_set1_ps(kInf), empty_hi = _mm_set1_ps(-kInf);
    for (int a = 0; a < 3; ++a)
      for (int i = 0; i < nb; ++i) bins[a][i] = {{empty_lo, empty_hi}, 0};
    const PrimRef* refs = refs_ + first;
    for (uint32_t i = 0; i < count; ++i) {
      const __m128 lo = _mm_load_ps(refs[i].lo), hi = _mm_load_ps(refs[i].hi);
      const __m128 c = _mm_add_ps(lo, hi);
      const __m128 f = _mm_min_ps(_mm_mul_ps(_mm_sub_ps(c, vmin), vscale), vmaxbin);
      alignas(16) int32_t b[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(b), _mm_cvttps_epi32(f));
      for (int a = 0; a < 3; ++a) {
        Bin& bin = bins[a][b[a]];
        bin.box.lo = _mm_min_ps(bin.box.lo, lo);
        bin.box.hi = _mm_max_ps(bin.box.hi, hi);
        ++bin.count;
      }
    }

    Split best;
    float right_area[kMaxBins];
    uint32_t right_count[kMaxBins];
    RawBox right_box[kMaxBins];
    for (int a = 0; a < 3; ++a) {
      if (!(cext[a] > 0.0f)) continue;
      // Right-to-left sweep: bounds and counts of bins [i, bins).
      Box4 acc;
      uint32_t n = 0;
      for (int i = nb - 1; i > 0; --i) {
        acc.grow(bins[a][i].box);
        n += bins[a][i].count;
        right_box[i] = {acc.lo, acc.hi};
        right_area[i] = half_area4(acc.lo, acc.hi);
        right_count[i] = n;
      }
      // Left-to-right sweep; candidate plane between bin i - 1 and bin i.
      Box4 lacc;
      uint32_t ln = 0;
      for (int i = 1; i < nb; ++i) {
        lacc.grow(bins[a][i - 1].box);
        ln += bins[a][i - 1].count;
        if (ln == 0 || right_count[i] == 0) continue;
        const float cost = half_area4(lacc.lo, lacc.hi) * blocks(ln) + right_area[i] * blocks(right_count[i]);
        if (cost < best.cost) {
          best.cost = cost;
          best.axis = a;
          best.bin = i;
          best.left = lacc;
          best.right = Box4(right_box[i]);
          best.left_count = ln;
        }
      }
    }
    if (best.axis >= 0) {
      best.bin_min = cmin[best.axis];
      best.bin_scale = scale[best.axis];
      best.bin_count = nb;
    }
    return best;
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
      lbox.grow(_mm_load_ps(p0.lo), _mm_load_ps(p0.hi));
      rbox.grow(_mm_load_ps(p1.lo), _mm_load_ps(p1.hi));
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
      const Split split = find_split(first, count, cbounds);
      if (split.axis >= 0) {
        const float leaf_cost = blocks(count);
        const float area = bounds.half_area();
        const float split_cost = traversal_cost_ + (area > 0.0f ? split.cost / area : leaf_cost);
        if (split_cost < leaf_cost || count > max_leaf_) {
          mid = partition(first, count, split, lcb, rcb);
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
    const int axis = split.axis;
    const float bmin = split.bin_min, bscale = split.bin_scale;
    const float maxbin = static_cast<float>(split.bin_count) - 1.0f;
    // Branchless Lomuto partition: which side a primitive goes to is a coin flip for the branch
    // predictor, so every element is swapped into place unconditionally and the left end only
    // advances for left elements; centroid bounds are grown through masks.
    const __m128 empty_lo = _mm_set1_ps(kInf), empty_hi = _mm_set1_ps(-kInf);
    uint32_t i = first;
    for (uint32_t k = first; k < first + count; ++k) {
      PrimRef r = refs_[k];
      const __m128 c = _mm_add_ps(_mm_load_ps(r.lo), _mm_load_ps(r.hi));
      const float ca = r.lo[axis] + r.hi[axis];
      const bool left = static_cast<int>(std::min((ca - bmin) * bscale, maxbin)) < split.bin;
      const __m128 m = _mm_castsi128_ps(_mm_set1_epi32(left ? -1 : 0));
      lcb.grow(_mm_or_ps(_mm_and_ps(m, c), _mm_andnot_ps(m, empty_lo)), _mm_or_ps(_mm_and_ps(m, c), _mm_andnot_ps(m, empty_hi)));
      rcb.grow(_mm_or_ps(_mm_andnot_ps(m, c), _mm_and_ps(m, empty_lo)), _mm_or_ps(_mm_andnot_ps(m, c), _mm_and_ps(m, empty_hi)));
      refs_[k] = refs_[i];
      refs_[i] = r;
      i += left ? 1u : 0u;
    }
    return i;
  }

  void range_bounds(uint32_t begin, uint32_t end, Box4& box, Box4& cbox) const {
    for (uint32_t i = begin; i < end; ++i) {
      const __m128 lo = _mm_load_ps(refs_[i].lo), hi = _mm_load_ps(refs_[i].hi);
      box.grow(lo, hi);
      const __m128 c = _mm_add_ps(lo, hi);
      cbox.grow(c, c);
    }
  }

  PrimRef* refs_;
  BvhNode* nodes_;
  int bins_;
  uint32_t max_leaf_;
  float traversal_cost_;
  std::atomic<uint32_t> next_node_{2};
};


namespace {

/// Bounds and centroid bounds of a set of PrimRefs (parallel_reduce body).
struct RootBounds {
  Box4 box, cbox;
  void join(const RootBounds& o) {
    box.grow(o.box);
    cbox.grow(o.cbox);
  }
};

}  // namespace

Bvh Bvh::build(const TriangleInput& input, const BvhOptions& options, BuildInfo* info) {
  const Timer timer;
  accel::validate_input(input);
  const size_t tri_count = input.indices.size() / 3;
  const uint32_t n = static_cast<uint32_t>(tri_count);
  const int threads = options.threads > 0 ? options.threads : tbb::info::default_concurrency();
  const bool parallel = threads > 1;

  Bvh bvh;
  tbb::task_arena arena(threads);
  arena.execute([&] {
    // 1. Primitive references and root bounds. Degenerate triangles get no reference (see
    //    accel::is_degenerate); the references of the others are compacted afterwards.
    std::unique_ptr<PrimRef[]> refs(new PrimRef[tri_count > 0 ? tri_count : 1]);
    std::unique_ptr<uint8_t[]> degenerate(new uint8_t[tri_count > 0 ? tri_count : 1]);
    const auto make_refs = [&](uint32_t begin, uint32_t end, RootBounds& rb) {
      for (uint32_t i = begin; i < end; ++i) {
        const Vec3& a = input.positions[input.indices[3 * size_t{i}]];
        const Vec3& b = input.positions[input.indices[3 * size_t{i} + 1]];
        const Vec3& c = input.positions[input.indices[3 * size_t{i} + 2]];
        degenerate[i] = accel::is_degenerate(a, b, c) ? 1 : 0;
        if (degenerate[i]) continue;
        const Vec3 lo = min(a, min(b, c)), hi = max(a, max(b, c));
        PrimRef& r = refs[i];
        r.lo[0] = lo.x, r.lo[1] = lo.y, r.lo[2] = lo.z;
        __builtin_memcpy(&r.lo[3], &i, sizeof(i));
        r.hi[0] = hi.x, r.hi[1] = hi.y, r.hi[2] = hi.z, r.hi[3] = 0.0f;
        const __m128 l4 = _mm_load_ps(r.lo), h4 = _mm_load_ps(r.hi);
        rb.box.grow(l4, h4);
        const __m128 c4 = _mm_add_ps(l4, h4);
        rb.cbox.grow(c4, c4);
      }
    };
    RootBounds root;
    if (parallel && n > kTaskThreshold) {
      root = tbb::parallel_reduce(
          tbb::blocked_range<uint32_t>(0, n, 1024), RootBounds{},
          [&](const tbb::blocked_range<uint32_t>& r, RootBounds rb) {
            make_refs(r.begin(), r.end(), rb);
            return rb;
          },
          [](RootBounds a, const RootBounds& b) {
            a.join(b);
            return a;
          });
    } else {
      make_refs(0, n, root);
    }
    uint32_t valid = 0;
    for (uint32_t i = 0; i < n; ++i) {
      if (degenerate[i]) continue;
      if (valid != i) refs[valid] = refs[i];
      ++valid;
    }
    // (Lane 3 of the bounds carries id bits; nothing reads it: only xyz reach the nodes.)

    // 2. Tree. At most 2n - 1 nodes plus the padding node.
    const size_t max_nodes = std::max<size_t>(2 * size_t{valid}, 2);
    std::unique_ptr<BvhNode[]> nodes(new BvhNode[max_nodes]);
    BvhBuilder builder(options, refs, nodes.get());
    builder.build_root(valid, root.box, root.cbox, parallel && valid > kTaskThreshold);
    const uint32_t used = builder.node_count();
    if (!parallel || valid <= kTaskThreshold) {
      bvh.nodes_.assign(nodes.get(), nodes.get() + used);
    } else {
      // Tasks allocated node pairs in whatever order they ran: renumber depth-first (left
      // subtree first), which is exactly the single-threaded layout, so the node array is
      // identical for any thread count and subtrees are contiguous in memory.
      bvh.nodes_.resize(used);
      bvh.nodes_[0] = nodes[0];
      uint32_t next = 2;
      std::vector<std::pair<uint32_t, uint32_t>> todo{{0u, 0u}};  // (old index, new index)
      while (!todo.empty()) {
        const auto [old_index, new_index] = todo.back();
        todo.pop_back();
        const BvhNode& src = nodes[old_index];
        if (src.is_leaf()) continue;
        const uint32_t left = next;
        next += 2;
        bvh.nodes_[new_index].left_first = left;
        bvh.nodes_[left] = nodes[src.left_first];
        bvh.nodes_[left + 1] = nodes[src.left_first + 1];
        todo.push_back({src.left_first + 1, left + 1});
        todo.push_back({src.left_first, left});
      }
    }
    bvh.nodes_[1] = BvhNode{};
    if (valid == 0) bvh.nodes_[0] = BvhNode{};

    // 3. Triangles and transmittance in BVH order.
    bvh.tris_.resize(valid);
    bvh.prim_ids_.resize(valid);
    const bool any_transparent =
        std::any_of(input.transmittance.begin(), input.transmittance.end(),
                    [](const Vec3& t) { return !accel::is_opaque(t); });
    if (any_transparent) bvh.transmittance_.resize(valid);
    const auto reorder = [&](uint32_t begin, uint32_t end) {
      for (uint32_t i = begin; i < end; ++i) {
        const uint32_t id = refs[i].id();
        bvh.prim_ids_[i] = id;
        BvhTriangle& t = bvh.tris_[i];
        for (int k = 0; k < 3; ++k) {
          const Vec3& p = input.positions[input.indices[3 * size_t{id} + static_cast<size_t>(k)]];
          t.v[3 * k] = p.x;
          t.v[3 * k + 1] = p.y;
          t.v[3 * k + 2] = p.z;
        }
        if (any_transparent) bvh.transmittance_[i] = input.transmittance[id];
      }
    };
    if (parallel && valid > kTaskThreshold) {
      tbb::parallel_for(tbb::blocked_range<uint32_t>(0, valid, 4096),
                        [&](const tbb::blocked_range<uint32_t>& r) { reorder(r.begin(), r.end()); });
    } else {
      reorder(0, valid);
    }
  });

  // 4. The 4-wide traversal layout: collapse every other level of the binary tree, opening
  //    the largest interior child first (as Embree's and Wald's BVH4 builders do).
  if (!bvh.tris_.empty()) {
    const auto& bin = bvh.nodes_;
    auto& wide = bvh.wide_;
    wide.reserve(bin.size() / 2 + 1);
    const auto half_area_of = [&bin](uint32_t i) {
      const Vec3 e = bin[i].max - bin[i].min;
      return e.x * e.y + e.y * e.z + e.z * e.x;
    };
    // Triangle blocks of the leaves, in the order the collapse meets them (depth first).
    auto& tri4 = bvh.tri4_;
    tri4.reserve(bvh.tris_.size() / 2 + 1);
    const auto make_blocks = [&](uint32_t first, uint32_t count) {
      const uint32_t index = static_cast<uint32_t>(tri4.size());
      for (uint32_t b = 0; b < count; b += kBlock)
        accel::fill_block(tri4.emplace_back(), bvh.tris_.data(), first + b, std::min(kBlock, count - b));
      return index;
    };
    const std::function<uint32_t(uint32_t)> collapse = [&](uint32_t b) -> uint32_t {
      uint32_t list[4];
      int k = 0;
      if (bin[b].is_leaf()) {
        list[k++] = b;
      } else {
        list[k++] = bin[b].left_first;
        list[k++] = bin[b].left_first + 1;
      }
      while (k < 4) {
        int open = -1;
        float best = -1.0f;
        for (int i = 0; i < k; ++i)
          if (!bin[list[i]].is_leaf() && half_area_of(list[i]) > best) best = half_area_of(list[i]), open = i;
        if (open < 0) break;
        const uint32_t l = bin[list[open]].left_first;
        list[open] = l;
        list[k++] = l + 1;
      }
      const uint32_t index = static_cast<uint32_t>(wide.size());
      wide.emplace_back();
      for (int i = 0; i < 4; ++i) {
        BvhWideNode& w = wide[index];
        if (i >= k) {
          for (int a = 0; a < 3; ++a) w.b[0][a][i] = kInf, w.b[1][a][i] = -kInf;
          w.child[i] = 0;
          w.count[i] = 0;
          continue;
        }
        const BvhNode& c = bin[list[i]];
        for (int a = 0; a < 3; ++a) w.b[0][a][i] = c.min[a], w.b[1][a][i] = c.max[a];
        w.count[i] = c.count;
        w.child[i] = c.is_leaf() ? make_blocks(c.left_first, c.count) : c.left_first;
        if (!c.is_leaf()) {
          const uint32_t sub = collapse(list[i]);
          wide[index].child[i] = sub;  // (wide may have reallocated)
        }
      }
      return index;
    };
    collapse(0);
  }

  // 5. Figures: node/leaf counts, depth and the SAH cost (root-area normalised), summed in
  //    depth-first order so the figures do not depend on the node numbering (thread count).
  BuildInfo& bi = bvh.info_;
  const size_t m = bvh.tris_.size();
  bi.nodes = m == 0 ? 1 : bvh.nodes_.size() - 1;  // minus the padding node
  const float tc = std::isfinite(options.traversal_cost) && options.traversal_cost >= 0.0f
                       ? options.traversal_cost
                       : 1.0f;
  const auto half_area = [](const BvhNode& nd) {
    const Vec3 e = nd.max - nd.min;
    return (e.x >= 0 && e.y >= 0 && e.z >= 0) ? double{e.x} * e.y + double{e.y} * e.z + double{e.z} * e.x : 0.0;
  };
  double sah = 0.0;
  size_t leaves = 0;
  uint32_t max_depth = 0;
  std::vector<std::pair<uint32_t, uint32_t>> stack{{0u, 0u}};
  while (!stack.empty()) {
    const auto [index, depth] = stack.back();
    stack.pop_back();
    const BvhNode& nd = bvh.nodes_[index];
    max_depth = std::max(max_depth, depth);
    if (nd.is_leaf() || m == 0) {
      ++leaves;
      sah += half_area(nd) * nd.count;
    } else {
      sah += half_area(nd) * tc;
      stack.push_back({nd.left_first + 1, depth + 1});
      stack.push_back({nd.left_first, depth + 1});
    }
  }
  bi.max_depth = max_depth;
  const double root_area = m > 0 ? half_area(bvh.nodes_[0]) : 0.0;
  bi.leaves = leaves;
  bi.sah_cost = root_area > 0.0 ? sah / root_area : static_cast<double>(m);
  bi.bytes = bvh.memory_bytes();
  bi.build_ms = timer.ms();
  if (info) *info = bi;
  return bvh;
}

Aabb Bvh::bounds() const {
  Aabb b;
  if (!tris_.empty()) {
    b.min = nodes_[0].min;
    b.max = nodes_[0].max;
  }
  return b;
}

size_t Bvh::memory_bytes() const {
  return nodes_.size() * sizeof(BvhNode) + wide_.size() * sizeof(BvhWideNode) + tris_.size() * sizeof(BvhTriangle) +
         tri4_.size() * sizeof(BvhTriangle4) +
         prim_ids_.size() * sizeof(uint32_t) + transmittance_.size() * sizeof(Vec3);
}

}  // namespace specula
