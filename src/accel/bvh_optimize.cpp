// Subtree reinsertion for binary BVHs (owner: accel). See bvh_optimize.h.
//
// The SAH cost of a binary tree is sum(area(interior) * Ct) + sum(area(leaf) * cost(leaf)),
// normalised by the root's area. Moving a subtree N (a leaf or an interior node) elsewhere
// leaves every leaf as it was, so only the interior nodes' areas change:
//  - removing N deletes its parent P (its sibling S takes P's place) and shrinks P's ancestors;
//  - inserting N beside a node X adds a new parent of area(X u N) and grows X's ancestors A by
//    area(A u N) - area(A).
// For a given N the cheapest X is found by a best-first search from the root ordered by the
// "induced" cost (the growth of X's ancestors), which only rises going down; the new parent's
// area is at least area(N), so a subtree whose induced cost plus area(N) cannot beat the best
// place found so far is never entered. The place N came from (beside S) is one of the
// candidates and restores the old cost exactly (min/max are exact), so a move never makes the
// tree worse.
//
// Which subtrees move: each round takes the nodes of the largest area (a share of all nodes;
// large boxes are where a misplaced subtree costs most, as Meister and Bittner 2018 select
// them), one after another, until a round gains less than a small fraction of the cost.
#include "accel/bvh_optimize.h"

#include <xmmintrin.h>  // SSE: x86-64 baseline

#include <algorithm>
#include <limits>
#include <vector>

namespace specula::accel {

namespace {

constexpr uint32_t kNone = 0xFFFFFFFFu;

/// Share of the nodes reinserted per round, rounds at most, and the relative gain below which a
/// round ends the pass.
constexpr double kBatchShare = 0.02;
constexpr size_t kMinBatch = 256;
constexpr int kMaxRounds = 8;
constexpr double kMinRoundGain = 1e-3;

struct Box {
  __m128 lo, hi;  // lane 3 = 0 in both
};

inline Box join(const Box& a, const Box& b) { return {_mm_min_ps(a.lo, b.lo), _mm_max_ps(a.hi, b.hi)}; }

/// Half the surface area, xy + yz + zx (lane 3 of both corners is 0).
inline float half_area(const Box& b) {
  const __m128 e = _mm_sub_ps(b.hi, b.lo);
  const __m128 r = _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1));  // y z x 0
  const __m128 p = _mm_mul_ps(e, r);                               // xy yz zx 0
  return _mm_cvtss_f32(_mm_add_ss(_mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1))), _mm_movehl_ps(p, p)));
}

inline bool same(const Box& a, const Box& b) {
  return _mm_movemask_ps(_mm_and_ps(_mm_cmpeq_ps(a.lo, b.lo), _mm_cmpeq_ps(a.hi, b.hi))) == 0xF;
}

/// The tree with parent links, as the pass edits it. Node identities are the input's indices.
class Tree {
 public:
  explicit Tree(std::span<const BvhNode> nodes) : n_(static_cast<uint32_t>(nodes.size())) {
    box_.resize(n_);
    area_.resize(n_);
    parent_.assign(n_, kNone);
    left_.assign(n_, kNone);
    right_.assign(n_, kNone);
    height_.assign(n_, 0);
    for (uint32_t j = 0; j < n_; ++j) {
      if (j == 1) continue;
      const BvhNode& nd = nodes[j];
      box_[j] = {_mm_setr_ps(nd.min.x, nd.min.y, nd.min.z, 0.0f), _mm_setr_ps(nd.max.x, nd.max.y, nd.max.z, 0.0f)};
      area_[j] = half_area(box_[j]);
      if (!nd.is_leaf()) {
        left_[j] = nd.left_first;
        right_[j] = nd.left_first + 1;
        parent_[nd.left_first] = parent_[nd.left_first + 1] = j;
      }
    }
    // Children follow their parents in the builder's array: heights in one backward pass.
    for (uint32_t j = n_; j-- > 0;)
      if (j != 1 && left_[j] != kNone) height_[j] = 1 + std::max(height_[left_[j]], height_[right_[j]]);
  }

  uint32_t root() const { return root_; }
  uint32_t height(uint32_t j) const { return height_[j]; }
  bool leaf(uint32_t j) const { return left_[j] == kNone; }
  float area(uint32_t j) const { return area_[j]; }
  uint32_t parent(uint32_t j) const { return parent_[j]; }

  /// Sum of the interior nodes' half areas (what reinsertion changes), in double.
  double interior_cost() const {
    double s = 0.0;
    for (uint32_t j = 0; j < n_; ++j)
      if (j != 1 && !leaf(j)) s += area_[j];
    return s;
  }

  /// Takes subtree \p x (not the root) out; its parent is freed and returned, and the sibling
  /// takes the parent's place.
  uint32_t remove(uint32_t x, uint32_t& sibling) {
    const uint32_t p = parent_[x];
    const uint32_t s = left_[p] == x ? right_[p] : left_[p];
    const uint32_t g = parent_[p];
    sibling = s;
    parent_[s] = g;
    if (g == kNone) {
      root_ = s;
    } else {
      (left_[g] == p ? left_[g] : right_[g]) = s;
      refit(g);
    }
    parent_[x] = kNone;
    return p;
  }

  /// Puts subtree \p x back as the sibling of \p at, under the free node \p p.
  void insert(uint32_t x, uint32_t at, uint32_t p) {
    const uint32_t g = parent_[at];
    left_[p] = at;
    right_[p] = x;
    parent_[p] = g;
    parent_[at] = p;
    parent_[x] = p;
    if (g == kNone)
      root_ = p;
    else
      (left_[g] == at ? left_[g] : right_[g]) = p;
    refit(p, true);
  }

  /// The cheapest place for subtree \p x (taken out) and its cost (the added area): a node at
  /// depth d whose subtree, one level deeper, and x beside it stay within \p max_depth.
  uint32_t best_place(uint32_t x, uint32_t max_depth) {
    const Box bx = box_[x];
    const double ax = area_[x];
    const uint32_t hx = height_[x];
    double best = std::numeric_limits<double>::infinity();
    uint32_t best_at = kNone;
    heap_.clear();
    heap_.push_back({0.0, root_, 0});
    const auto later = [](const Entry& a, const Entry& b) {
      return a.induced != b.induced ? a.induced > b.induced : a.node > b.node;
    };
    while (!heap_.empty()) {
      std::pop_heap(heap_.begin(), heap_.end(), later);
      const Entry e = heap_.back();
      heap_.pop_back();
      if (e.induced + ax >= best) break;  // every entry left is at least as dear
      const uint32_t at = e.node;
      const double joined = half_area(join(box_[at], bx));
      const double cost = e.induced + joined;
      if (cost < best && e.depth + 1 + std::max(hx, height_[at]) <= max_depth) {
        best = cost;
        best_at = at;
      }
      if (leaf(at)) continue;
      const double below = cost - area_[at];  // the induced cost of at's children
      // (Areas that overflowed to inf make this NaN: such subtrees are not searched, which
      // also keeps NaN out of the heap's ordering.)
      if (!(below + ax < best)) continue;
      heap_.push_back({below, left_[at], e.depth + 1});
      std::push_heap(heap_.begin(), heap_.end(), later);
      heap_.push_back({below, right_[at], e.depth + 1});
      std::push_heap(heap_.begin(), heap_.end(), later);
    }
    return best_at;
  }

  /// Writes the tree back in the builder's layout: depth-first numbering (left subtree
  /// first; a node's children as the pair allocated when it is reached), leaves' triangles
  /// renumbered in the same order so every subtree's range is contiguous.
  void write(std::span<BvhNode> nodes, std::span<uint32_t> prim_ids) const {
    const std::vector<BvhNode> old(nodes.begin(), nodes.end());
    const std::vector<uint32_t> old_ids(prim_ids.begin(), prim_ids.end());
    uint32_t next_node = 2, next_prim = 0;
    std::vector<std::pair<uint32_t, uint32_t>> todo{{root_, 0u}};  // (tree node, new index)
    while (!todo.empty()) {
      const auto [t, k] = todo.back();
      todo.pop_back();
      BvhNode& out = nodes[k];
      float lo[4], hi[4];
      _mm_storeu_ps(lo, box_[t].lo);
      _mm_storeu_ps(hi, box_[t].hi);
      out.min = {lo[0], lo[1], lo[2]};
      out.max = {hi[0], hi[1], hi[2]};
      if (leaf(t)) {
        const BvhNode& src = old[t];
        out.count = src.count;
        out.left_first = next_prim;
        std::copy_n(old_ids.begin() + src.left_first, src.count, prim_ids.begin() + next_prim);
        next_prim += src.count;
        continue;
      }
      out.count = 0;
      out.left_first = next_node;
      next_node += 2;
      todo.push_back({right_[t], out.left_first + 1});
      todo.push_back({left_[t], out.left_first});
    }
    nodes[1] = BvhNode{};
  }

 private:
  struct Entry {
    double induced;
    uint32_t node;
    uint32_t depth;
  };

  /// Recomputes boxes, areas and heights from \p j up to the root; stops where nothing changes
  /// (unless \p force for the first node, which is new).
  void refit(uint32_t j, bool force = false) {
    for (; j != kNone; j = parent_[j], force = false) {
      const Box b = join(box_[left_[j]], box_[right_[j]]);
      const uint32_t h = 1 + std::max(height_[left_[j]], height_[right_[j]]);
      if (!force && same(b, box_[j]) && h == height_[j]) return;
      box_[j] = b;
      area_[j] = half_area(b);
      height_[j] = h;
    }
  }

  uint32_t n_;
  uint32_t root_ = 0;
  std::vector<Box> box_;
  std::vector<float> area_;
  std::vector<uint32_t> parent_, left_, right_, height_;
  std::vector<Entry> heap_;
};

}  // namespace

ReinsertionStats optimize_by_reinsertion(std::span<BvhNode> nodes, std::span<uint32_t> prim_ids, uint32_t max_depth) {
  ReinsertionStats st;
  if (nodes.size() < 5 || nodes[0].is_leaf()) return st;  // a root and two leaves at least to move anything
  Tree tree(nodes);
  max_depth = std::max(max_depth, tree.height(tree.root()));
  st.cost_before = st.cost_after = tree.interior_cost();
  const uint32_t n = static_cast<uint32_t>(nodes.size());
  std::vector<uint32_t> order;
  order.reserve(n);
  // (Small trees: all their nodes each round.)
  const size_t batch = std::max<size_t>(std::min<size_t>(n, kMinBatch), static_cast<size_t>(kBatchShare * static_cast<double>(n)));
  for (int round = 0; round < kMaxRounds; ++round) {
    order.clear();
    for (uint32_t j = 0; j < n; ++j)
      if (j != 1 && j != tree.root()) order.push_back(j);
    const size_t take = std::min(batch, order.size());
    // Largest first; equal areas by index (a deterministic order). A NaN area (inf times a
    // flat extent, near the float range's end) ranks last, so the order stays strict.
    const auto key = [&tree](uint32_t a) {
      const float x = tree.area(a);
      return x == x ? x : -std::numeric_limits<float>::infinity();
    };
    const auto larger = [&key](uint32_t a, uint32_t b) { return key(a) != key(b) ? key(a) > key(b) : a < b; };
    std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(take), order.end(), larger);
    for (size_t i = 0; i < take; ++i) {
      const uint32_t x = order[i];
      if (tree.parent(x) == kNone) continue;  // x became the root earlier in this round
      uint32_t sibling = kNone;
      const uint32_t p = tree.remove(x, sibling);
      uint32_t at = tree.best_place(x, max_depth);
      if (at == kNone) at = sibling;  // (the old place always qualifies; defensive)
      tree.insert(x, at, p);
      st.moves += at != sibling;
    }
    ++st.rounds;
    const double cost = tree.interior_cost();
    const double gain = st.cost_after - cost;
    st.cost_after = cost;
    if (!(gain > kMinRoundGain * cost)) break;
  }
  tree.write(nodes, prim_ids);
  return st;
}

}  // namespace specula::accel
