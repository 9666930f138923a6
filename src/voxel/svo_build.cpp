// Sparse voxel octree: bottom-up build from sorted Morton codes, level-of-detail attributes,
// structure checks and level extraction (owner: voxel tracers).
//
// Build: the codes of level l are the unique codes of level l + 1 shifted right by 3 (sorted
// input stays sorted), each with the mask of the children it collected. Nodes are then laid
// out level by level (breadth first), so a node's first child index is simply the running
// count of children before it; that also makes the structure checkable in one pass (files).
// Memory: one code and one mask byte per node during the build, nothing per empty cell.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "core/memory.h"
#include "specula/error.h"
#include "specula/svo.h"
#include "specula/timer.h"
#include "voxel/voxel_brute.h"

#include <emmintrin.h>  // SSE2: x86-64 baseline
#include <xmmintrin.h>

namespace specula {

namespace {

/// Per child mask: the slots of the children in order (the set bits, low to high; 0 past the
/// last) and their count.
struct SlotList {
  std::array<uint8_t, 8> slot{};
  int count = 0;
};
constexpr std::array<SlotList, 256> kSlotLists = [] {
  std::array<SlotList, 256> t{};
  for (uint32_t m = 0; m < 256; ++m)
    for (uint32_t s = 0; s < 8; ++s)
      if ((m >> s) & 1u) t[m].slot[static_cast<size_t>(t[m].count++)] = static_cast<uint8_t>(s);
  return t;
}();

/// Averaged attributes of one inner node from its children: \p n children stored contiguously
/// at \p child, in slot order (the set bits of the node's mask, \p slots). Weights = voxel
/// counts; kUnitWeights: every weight is 1 (the children are voxels) and the products by the
/// weights are left out (x * 1.0f == x). \p child_half is the children's half side in world
/// units. Normal: the weighted sum normalised (else the heaviest child's, else +z); material:
/// the heaviest child's. Conservative contours: dot(n, p - C) bounded over each child's cube
/// intersected with its slab, as the intersection of two valid bounds: the child cube alone
/// (h |n|_1), and the child slab after writing n = k n_c + r: k [lo_c, hi_c] + [-h |r|_1,
/// h |r|_1].
/// In SSE2 (the x86-64 baseline), with the operations of the scalar formulation it replaced
/// (git history: svo_build.cpp before 2026-12-02), so the same bits: the sums run over the
/// children in order with the attribute fields as lanes (normal + red, green + blue +
/// reflectivity + transparency, ior), the contour bounds of four children at a time run as
/// lanes (selects for the branches; std::max(a, b) is _mm_max_ps(b, a) and std::min(a, b) is
/// _mm_min_ps(b, a), signed zeros and NaNs included), then the min/max fold over the children
/// stays sequential in child order.
template <bool kUnitWeights>
[[gnu::always_inline]] inline VoxelAttributes average_children(const VoxelAttributes* child, const uint32_t* weights,
                                                               const uint8_t* slots, int n, float child_half) {
  static_assert(sizeof(VoxelAttributes) == 48 && offsetof(VoxelAttributes, colour) == 12 &&
                offsetof(VoxelAttributes, reflectivity) == 24 && offsetof(VoxelAttributes, ior) == 32 &&
                offsetof(VoxelAttributes, contour_lo) == 36 && offsetof(VoxelAttributes, material) == 44);
  const auto load = [](const VoxelAttributes* a, size_t offset) {
    __m128 v;
    std::memcpy(&v, reinterpret_cast<const char*>(a) + offset, sizeof v);
    return v;
  };
  const __m128 first_lane = _mm_castsi128_ps(_mm_set_epi32(0, 0, 0, -1));
  __m128 s0 = _mm_setzero_ps(), s1 = _mm_setzero_ps(), s2 = _mm_setzero_ps();
  float wsum = 0.0f;
  int heaviest = 0;
  for (int i = 0; i < n; ++i) {
    const __m128 v0 = load(child + i, 0), v1 = load(child + i, 16);
    const __m128 v2 = _mm_and_ps(load(child + i, 32), first_lane);  // ior only
    if constexpr (kUnitWeights) {
      s0 = _mm_add_ps(s0, v0);
      s1 = _mm_add_ps(s1, v1);
      s2 = _mm_add_ps(s2, v2);
      wsum += 1.0f;
    } else {
      const float w = static_cast<float>(weights[i]);
      const __m128 wv = _mm_set1_ps(w);
      s0 = _mm_add_ps(s0, _mm_mul_ps(v0, wv));
      s1 = _mm_add_ps(s1, _mm_mul_ps(v1, wv));
      s2 = _mm_add_ps(s2, _mm_mul_ps(v2, wv));
      wsum += w;
      if (weights[i] > weights[heaviest]) heaviest = i;
    }
  }
  const __m128 inv = _mm_set1_ps(1.0f / wsum);
  VoxelAttributes out;
  {
    const __m128 o0 = _mm_mul_ps(s0, inv);  // lane 3: red
    const __m128 o1 = _mm_mul_ps(s1, inv);  // green, blue, reflectivity, transparency
    std::memcpy(reinterpret_cast<char*>(&out) + 16, &o1, sizeof o1);
    out.colour.x = _mm_cvtss_f32(_mm_shuffle_ps(o0, o0, _MM_SHUFFLE(3, 3, 3, 3)));
    out.ior = _mm_cvtss_f32(_mm_mul_ss(s2, inv));
  }
  out.material = child[heaviest].material;
  alignas(16) float ns[4];
  _mm_store_ps(ns, s0);
  Vec3 nrm = normalize(Vec3{ns[0], ns[1], ns[2]});
  if (nrm == Vec3{}) nrm = normalize(child[heaviest].normal);
  if (nrm == Vec3{}) nrm = Vec3{0.0f, 0.0f, 1.0f};
  out.normal = nrm;

  const float l1n = std::fabs(nrm.x) + std::fabs(nrm.y) + std::fabs(nrm.z);
  const float cube = child_half * l1n;
  const __m128 h = _mm_set1_ps(child_half), nx = _mm_set1_ps(nrm.x), ny = _mm_set1_ps(nrm.y),
               nz = _mm_set1_ps(nrm.z);
  const __m128 zero = _mm_setzero_ps(), sign = _mm_set1_ps(-0.0f);
  const __m128 clo = _mm_set1_ps(-cube), chi = _mm_set1_ps(cube);
  const auto select = [](__m128 m, __m128 a, __m128 b) { return _mm_or_ps(_mm_and_ps(m, a), _mm_andnot_ps(m, b)); };
  const auto abs = [&](__m128 v) { return _mm_andnot_ps(sign, v); };
  // (slot & bit) ? h : -h
  const auto half = [&](__m128i s, int bit) {
    const __m128i off = _mm_cmpeq_epi32(_mm_and_si128(s, _mm_set1_epi32(bit)), _mm_setzero_si128());
    return _mm_xor_ps(h, _mm_and_ps(sign, _mm_castsi128_ps(off)));
  };
  alignas(16) float los[8], his[8];
  for (int j = 0; j < n; j += 4) {
    // Lanes past the last child repeat it (results unused).
    const int i1 = std::min(j + 1, n - 1), i2 = std::min(j + 2, n - 1), i3 = std::min(j + 3, n - 1);
    __m128 ax = load(child + j, 0), ay = load(child + i1, 0), az = load(child + i2, 0), a3 = load(child + i3, 0);
    _MM_TRANSPOSE4_PS(ax, ay, az, a3);
    __m128 b0 = load(child + j, 32), clo_c = load(child + i1, 32), chi_c = load(child + i2, 32),
           b3 = load(child + i3, 32);
    _MM_TRANSPOSE4_PS(b0, clo_c, chi_c, b3);
    uint32_t four;  // slots j..j+3 (the table holds 8)
    std::memcpy(&four, slots + j, sizeof four);
    const __m128i s = _mm_unpacklo_epi16(
        _mm_unpacklo_epi8(_mm_cvtsi32_si128(static_cast<int>(four)), _mm_setzero_si128()), _mm_setzero_si128());
    const __m128 offs = _mm_add_ps(_mm_add_ps(_mm_mul_ps(nx, half(s, 1)), _mm_mul_ps(ny, half(s, 2))),
                                   _mm_mul_ps(nz, half(s, 4)));
    const __m128 nn = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ax, ax), _mm_mul_ps(ay, ay)), _mm_mul_ps(az, az));
    const __m128 dn = _mm_add_ps(_mm_add_ps(_mm_mul_ps(nx, ax), _mm_mul_ps(ny, ay)), _mm_mul_ps(nz, az));
    const __m128 k = _mm_div_ps(dn, nn);
    const __m128 rx = _mm_sub_ps(nx, _mm_mul_ps(ax, k)), ry = _mm_sub_ps(ny, _mm_mul_ps(ay, k)),
                 rz = _mm_sub_ps(nz, _mm_mul_ps(az, k));
    const __m128 rb = _mm_mul_ps(h, _mm_add_ps(_mm_add_ps(abs(rx), abs(ry)), abs(rz)));
    const __m128 kpos = _mm_cmpge_ps(k, zero);
    const __m128 klo = _mm_mul_ps(k, clo_c), khi = _mm_mul_ps(k, chi_c);
    const __m128 slo = _mm_sub_ps(select(kpos, klo, khi), rb);
    const __m128 shi = _mm_add_ps(select(kpos, khi, klo), rb);
    const __m128 mx = _mm_max_ps(slo, clo);  // std::max(clo, slo)
    const __m128 mn = _mm_min_ps(shi, chi);  // std::min(chi, shi)
    const __m128 use = _mm_and_ps(_mm_cmple_ps(mx, mn), _mm_cmpgt_ps(nn, zero));
    _mm_store_ps(los + j, _mm_add_ps(offs, select(use, mx, clo)));
    _mm_store_ps(his + j, _mm_add_ps(offs, select(use, mn, chi)));
  }
  float lo = kInf, hi = -kInf;
  for (int i = 0; i < n; ++i) {
    lo = std::min(lo, los[i]);
    hi = std::max(hi, his[i]);
  }
  const float pad = 8e-6f * child_half;  // covers the rounding of the sums above
  out.contour_lo = lo - pad;
  out.contour_hi = hi + pad;
  return out;
}

// The averaging compiled twice (baseline x86-64 and x86-64-v3, i.e. AVX2: three-operand VEX
// forms, no register copies), the right one chosen at load time. Both give identical results
// (the same operations; no contraction into FMA: -ffp-contract=off).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define SPECULA_SVO_CLONES [[gnu::flatten, gnu::target_clones("default", "arch=x86-64-v3")]]
#else
#define SPECULA_SVO_CLONES [[gnu::flatten]]
#endif
/// average_children of the voxels under a node with child mask \p mask, into \p out.
SPECULA_SVO_CLONES
void average_voxels(const VoxelAttributes* child, uint32_t mask, float child_half, VoxelAttributes* out) {
  const SlotList& sl = kSlotLists[mask & 0xFFu];
  *out = average_children<true>(child, nullptr, sl.slot.data(), sl.count, child_half);
}
/// average_children of the inner nodes under a node with child mask \p mask (weights = their
/// voxel counts), into \p out.
SPECULA_SVO_CLONES
void average_nodes(const VoxelAttributes* child, const uint32_t* weights, uint32_t mask, float child_half,
                   VoxelAttributes* out) {
  const SlotList& sl = kSlotLists[mask & 0xFFu];
  *out = average_children<false>(child, weights, sl.slot.data(), sl.count, child_half);
}

/// validate_set's test of voxel attributes (every float finite, contour_lo <= contour_hi) over a
/// run of voxels, branch-free: the lanes' x - x summed over all of them (0 while every float is
/// finite, NaN from the first that is not: NaN + anything is NaN), the contour_lo <= contour_hi
/// tests or-ed; bad() is true iff some voxel fails.
class FiniteCheck {
 public:
  void add(const VoxelAttributes& a) {
    Float4 u, v;
    Int4 m;
    const char* p = reinterpret_cast<const char*>(&a);
    std::memcpy(&u, p, sizeof u);
    std::memcpy(&v, p + 16, sizeof v);
    std::memcpy(&m, p + 32, sizeof m);
    const Float4 w = reinterpret_cast<Float4>(m & Int4{-1, -1, -1, 0});  // the material id: not a float
    acc_ += ((u - u) + (v - v)) + (w - w);
    unordered_ |= !(a.contour_lo <= a.contour_hi);
  }
  bool bad() const { return !((acc_[0] + acc_[1]) + (acc_[2] + acc_[3]) == 0.0f) || unordered_; }

 private:
  typedef float Float4 __attribute__((vector_size(16)));
  typedef int32_t Int4 __attribute__((vector_size(16)));
  Float4 acc_{};
  bool unordered_ = false;
};

/// FiniteCheck of one voxel.
bool finite_attrs(const VoxelAttributes& a) {
  FiniteCheck check;
  check.add(a);
  return !check.bad();
}

/// What the parallel checks found invalid: voxel::validate_set() on a copy then throws its exact
/// message (only on this path, so the copy costs nothing in a valid build).
[[noreturn]] void reject(const VoxelSet& set, const std::vector<VoxelAttributes>* attrs) {
  VoxelSet copy;
  copy.grid = set.grid;
  copy.codes = set.codes;
  copy.attrs = attrs ? *attrs : set.attrs;
  voxel::validate_set(copy, "svo");
  throw Error("svo: invalid voxel set");  // not reached: the checks here are validate_set's
}

/// A run of voxels holding whole subtrees below the split level k: the nodes it creates at
/// each level k..depth-1 are contiguous in that level, so chunks build in parallel.
struct Chunk {
  size_t begin = 0, end = 0;                                  ///< voxel range
  std::array<uint32_t, kMaxVoxelDepth + 1> count{};           ///< nodes per level (k..depth-1)
  std::array<uint32_t, kMaxVoxelDepth + 1> first{};           ///< their first node index per level
  std::vector<uint64_t> top;                                  ///< codes of its level-k nodes
  bool bad_codes = false, bad_attrs = false;
};

/// First level (>= k) at which voxel code \p c starts new nodes after voxel code \p prev: the
/// nodes of level l are the codes shifted right by 3 (depth - l).
inline int split_level(uint64_t c, uint64_t prev, int depth, int k) {
  const int h = 63 - std::countl_zero(c ^ prev);  // c != prev (checked)
  return std::max(k, depth - h / 3);
}

}  // namespace

SparseVoxelOctree SparseVoxelOctree::build(const VoxelSet& set, const VoxelTracerOptions& options, SvoInfo* info) {
  return build_from(set, nullptr, options, info, Timer());
}

SparseVoxelOctree SparseVoxelOctree::build(VoxelSet&& set, const VoxelTracerOptions& options, SvoInfo* info) {
  const Timer timer;
  std::vector<VoxelAttributes> attrs;
  if (!set.attrs.empty() && set.attrs.size() == set.codes.size()) attrs.swap(set.attrs);  // checked in build_from
  try {
    return build_from(set, attrs.empty() ? nullptr : &attrs, options, info, timer);
  } catch (...) {
    if (set.attrs.empty()) set.attrs.swap(attrs);  // an invalid set is left as it was given
    throw;
  }
}

SparseVoxelOctree SparseVoxelOctree::build_from(const VoxelSet& set, std::vector<VoxelAttributes>* steal,
                                                const VoxelTracerOptions& options, SvoInfo* info,
                                                const Timer& timer) {
  // The set's grid and sizes first (validate_set on the grid alone), then codes and attribute
  // values in parallel: codes before anything is laid out, attribute values while the leaves'
  // parents average them. Any failure: validate_set's message (reject()).
  {
    VoxelSet grid_only;
    grid_only.grid = set.grid;
    voxel::validate_set(grid_only, "svo");
    const size_t n = set.codes.size();
    if ((!set.attrs.empty() && set.attrs.size() != n) ||
        n >= (size_t{1} << 31) / static_cast<size_t>(std::max(set.grid.depth, 1)))
      reject(set, steal);
  }
  SparseVoxelOctree svo;
  svo.grid_ = set.grid;
  svo.mode_ = options.mode;
  svo.set_lod(options.lod);
  const int depth = set.grid.depth;
  const size_t n = set.codes.size();
  const uint64_t* codes = set.codes.data();
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  const int threads = options.threads > 0 ? options.threads : arena.max_concurrency();

  if (depth == 0 || n == 0) {
    // Trivial sets: the serial checks, then a lone root (an empty tree is a root without children).
    const std::vector<VoxelAttributes>& given = steal ? *steal : set.attrs;
    if (n > 1 || (n == 1 && (codes[0] != 0 || (!given.empty() && !finite_attrs(given[0]))))) reject(set, steal);
    svo.leaf_attrs_ = steal ? std::move(*steal) : voxel::attributes_or_default(set);
    if (depth == 0) {
      svo.level_offsets_ = {0};
    } else {
      svo.level_offsets_.assign(static_cast<size_t>(depth) + 1, 1);
      svo.level_offsets_[0] = 0;
      svo.nodes_.assign(1, SvoNode{depth > 1 ? 1u : 0u, 0u});
      svo.inner_attrs_.assign(1, VoxelAttributes{});
    }
    if (info) *info = svo.info(), info->build_ms = timer.ms();
    return svo;
  }

  // Split level k: levels k..depth-1 are built by chunks of voxels in parallel, levels 0..k-1
  // (at most 8^k - 1 nodes) serially from the chunks' level-k codes.
  const int k = std::min(depth - 1, 5);
  const int top_shift = 3 * (depth - k);
  const uint64_t limit = uint64_t{1} << (3 * depth);
  std::vector<Chunk> chunks;
  {
    const size_t want = std::clamp<size_t>(n / 16384, 1, static_cast<size_t>(16 * threads));
    size_t b = 0;
    for (size_t c = 1; c <= want && b < n; ++c) {
      size_t e = c == want ? n : std::max(b + 1, n * c / want);
      while (e < n && (codes[e] >> top_shift) == (codes[e - 1] >> top_shift)) ++e;
      Chunk ch;
      ch.begin = b;
      ch.end = e;
      chunks.push_back(std::move(ch));
      b = e;
    }
  }
  const auto for_chunks = [&](auto&& f) {
    if (chunks.size() == 1 || threads == 1) {
      for (Chunk& ch : chunks) f(ch);
    } else {
      arena.execute([&] {
        tbb::parallel_for(size_t{0}, chunks.size(), [&](size_t c) { f(chunks[c]); });
      });
    }
  };

  // Pass 1: check the codes (in range, increasing), count the nodes per level, collect the
  // level-k codes.
  for_chunks([&](Chunk& ch) {
    std::array<uint32_t, kMaxVoxelDepth + 1> starts{};  // nodes opening at exactly level L
    // Locals (not reloaded after the stores). The previous code: before the first voxel all
    // ones (c + 1 <= prev + 1 never holds, as c < limit <= 2^63; and c differs from it in bit
    // 63, so split_level gives k), else the previous chunk's last code (which differs in the
    // level-k code when the codes are valid: split_level gives k too).
    const uint64_t* const code = codes;
    const size_t end = ch.end;
    const int d = depth, top = k;
    uint64_t prev = ch.begin > 0 ? code[ch.begin - 1] : ~uint64_t{0};
    for (size_t i = ch.begin; i < end; ++i) {
      const uint64_t c = code[i];
      if (c >= limit || c + 1 <= prev + 1) {
        ch.bad_codes = true;
        return;
      }
      const int L = split_level(c, prev, d, top);
      prev = c;
      if (L >= d) continue;
      ++starts[static_cast<size_t>(L)];
      if (L == k) ch.top.push_back(c >> top_shift);
    }
    uint32_t run = 0;
    for (int l = k; l < depth; ++l) ch.count[static_cast<size_t>(l)] = run += starts[static_cast<size_t>(l)];
  });
  for (const Chunk& ch : chunks)
    if (ch.bad_codes) reject(set, steal);

  // Levels 0..k-1: the old bottom-up merge of the level-k codes (sorted: chunks are in order).
  std::vector<std::vector<uint64_t>> up_codes(static_cast<size_t>(k) + 1);
  std::vector<std::vector<uint8_t>> up_masks(static_cast<size_t>(k));
  for (const Chunk& ch : chunks) up_codes[static_cast<size_t>(k)].insert(up_codes[static_cast<size_t>(k)].end(), ch.top.begin(), ch.top.end());
  for (int l = k - 1; l >= 0; --l) {
    auto& c = up_codes[static_cast<size_t>(l)];
    auto& m = up_masks[static_cast<size_t>(l)];
    for (const uint64_t code : up_codes[static_cast<size_t>(l) + 1]) {
      const uint64_t parent = code >> 3;
      if (c.empty() || c.back() != parent) {
        c.push_back(parent);
        m.push_back(0);
      }
      m.back() = static_cast<uint8_t>(m.back() | (1u << (code & 7u)));
    }
  }

  // Breadth-first layout: level sizes, each chunk's first node per level.
  svo.level_offsets_.assign(static_cast<size_t>(depth) + 1, 0);
  for (int l = 0; l < depth; ++l) {
    size_t size = 0;
    if (l < k) {
      size = up_codes[static_cast<size_t>(l)].size();
    } else {
      for (const Chunk& ch : chunks) size += ch.count[static_cast<size_t>(l)];
    }
    svo.level_offsets_[static_cast<size_t>(l) + 1] = svo.level_offsets_[static_cast<size_t>(l)] + static_cast<uint32_t>(size);
  }
  for (int l = k; l < depth; ++l) {
    uint32_t at = svo.level_offsets_[static_cast<size_t>(l)];
    for (Chunk& ch : chunks) {
      ch.first[static_cast<size_t>(l)] = at;
      at += ch.count[static_cast<size_t>(l)];
    }
  }
  const size_t node_count = svo.level_offsets_.back();
  // Written once each below (no zero-fill: the pages are first touched by the parallel pass).
  svo.nodes_.reserve(node_count);
  svo.inner_attrs_.reserve(node_count);
  prepare_for_writes(svo.nodes_.data(), node_count * sizeof(SvoNode));
  prepare_for_writes(svo.inner_attrs_.data(), node_count * sizeof(VoxelAttributes));
  svo.nodes_.resize(node_count);
  svo.inner_attrs_.resize(node_count);
  const std::unique_ptr<uint32_t[]> counts(new uint32_t[node_count]);  // voxels below each node
  svo.leaf_attrs_ = steal ? std::move(*steal) : voxel::attributes_or_default(set);

  SvoNode* nodes = svo.nodes_.data();
  VoxelAttributes* inner = svo.inner_attrs_.data();
  const VoxelAttributes* leaves = svo.leaf_attrs_.data();
  std::array<float, kMaxVoxelDepth + 1> child_halves{};  // per level: the children's half side
  for (int l = 0; l < depth; ++l)
    child_halves[static_cast<size_t>(l)] = 0.25f * set.grid.side / static_cast<float>(1u << l);
  const auto close = [&](uint32_t idx, int l) {  // averages node idx (level l) from its children
    const SvoNode node = nodes[idx];
    const float child_half = child_halves[static_cast<size_t>(l)];
    const int m = kSlotLists[node.mask & 0xFFu].count;
    if (l == depth - 1) {
      counts[idx] = static_cast<uint32_t>(m);
      average_voxels(&leaves[node.first_child], node.mask, child_half, &inner[idx]);
    } else {
      const uint32_t* weights = &counts[node.first_child];
      uint32_t total = 0;
      for (int i = 0; i < m; ++i) total += weights[i];
      counts[idx] = total;
      average_nodes(&inner[node.first_child], weights, node.mask, child_half, &inner[idx]);
    }
  };

  // Pass 2: nodes of levels k..depth-1 in voxel order, each averaged when its last child is done.
  for_chunks([&](Chunk& ch) {
    // The open node of each level, and its child mask so far (stored when it closes).
    std::array<uint32_t, kMaxVoxelDepth + 1> next = ch.first, open{}, mask{};
    const size_t last = static_cast<size_t>(depth) - 1;
    // Locals (not reloaded through the captures after every store) and the voxels' mask,
    // mask[last], in a register while its node is open.
    const uint64_t* const code = codes;
    const VoxelAttributes* const leaf = leaves;
    SvoNode* const node = nodes;
    const size_t begin = ch.begin, end = ch.end;
    const int d = depth, top = k;
    uint32_t leaf_mask = 0;
    FiniteCheck check;
    uint64_t prev = code[begin] ^ (uint64_t{1} << 63);  // differs in bit 63: the first voxel opens level k
    for (size_t i = begin; i < end; ++i) {
      const uint64_t c = code[i];
      const int L = split_level(c, prev, d, top);
      prev = c;
      if (L < d) {
        mask[last] = leaf_mask;
        if (i > begin)
          for (int l = d - 1; l >= L; --l) {
            const auto ul = static_cast<size_t>(l);
            node[open[ul]].mask = mask[ul];
            close(open[ul], l);
          }
        for (int l = L; l < d; ++l) {
          const auto ul = static_cast<size_t>(l);
          const uint32_t idx = next[ul]++;
          open[ul] = idx;
          node[idx].first_child = ul == last ? static_cast<uint32_t>(i) : next[ul + 1];
        }
        // The voxel's bits: a child of the node of level L - 1 (open before), the first of the
        // nodes it opens (their masks start from it).
        if (L > top) mask[static_cast<size_t>(L) - 1] |= 1u << ((c >> (3 * (d - L))) & 7u);
        for (int l = L; l < d - 1; ++l) mask[static_cast<size_t>(l)] = 1u << ((c >> (3 * (d - 1 - l))) & 7u);
        leaf_mask = 0;
      }
      leaf_mask |= 1u << (c & 7u);
      check.add(leaf[i]);
    }
    mask[last] = leaf_mask;
    for (int l = depth - 1; l >= k; --l) {
      const auto ul = static_cast<size_t>(l);
      nodes[open[ul]].mask = mask[ul];
      close(open[ul], l);
    }
    ch.bad_attrs = check.bad();
  });
  for (const Chunk& ch : chunks) {
    if (!ch.bad_attrs) continue;
    if (!steal) reject(set, nullptr);
    *steal = std::move(svo.leaf_attrs_);  // back to the caller (build(VoxelSet&&) restores the set)
    reject(set, steal);
  }

  // Levels k-1..0: nodes, then their averages bottom-up.
  for (int l = 0; l < k; ++l) {
    uint32_t running = svo.level_offsets_[static_cast<size_t>(l) + 1];
    const auto& m = up_masks[static_cast<size_t>(l)];
    const uint32_t base = svo.level_offsets_[static_cast<size_t>(l)];
    for (size_t j = 0; j < m.size(); ++j) {
      nodes[base + j] = SvoNode{running, m[j]};
      running += static_cast<uint32_t>(std::popcount(static_cast<unsigned>(m[j])));
    }
  }
  for (int l = k - 1; l >= 0; --l)
    for (uint32_t i = svo.level_offsets_[static_cast<size_t>(l)]; i < svo.level_offsets_[static_cast<size_t>(l) + 1]; ++i)
      close(i, l);

  if (info) {
    *info = svo.info();
    info->build_ms = timer.ms();
  }
  return svo;
}

void SparseVoxelOctree::set_lod(int lod) {
  if (lod < 0) throw Error("svo: level of detail must be >= 0 (got " + std::to_string(lod) + ")");
  lod_ = lod;
}

size_t SparseVoxelOctree::memory_bytes() const {
  return nodes_.size() * sizeof(SvoNode) + (leaf_attrs_.size() + inner_attrs_.size()) * sizeof(VoxelAttributes) +
         level_offsets_.size() * sizeof(uint32_t);
}

SvoInfo SparseVoxelOctree::info() const {
  SvoInfo i;
  i.nodes = nodes_.size();
  i.voxels = leaf_attrs_.size();
  i.bytes = memory_bytes();
  if (i.voxels > 0) {
    i.node_bytes_per_voxel = static_cast<double>(i.nodes * sizeof(SvoNode)) / static_cast<double>(i.voxels);
    i.bytes_per_voxel = static_cast<double>(i.bytes) / static_cast<double>(i.voxels);
  }
  return i;
}

const VoxelAttributes& SparseVoxelOctree::attributes(uint32_t prim) const {
  if (prim < leaf_attrs_.size()) return leaf_attrs_[prim];
  const size_t inner = prim - leaf_attrs_.size();
  if (inner < inner_attrs_.size()) return inner_attrs_[inner];
  throw Error("svo: prim " + std::to_string(prim) + " out of range (" + std::to_string(leaf_attrs_.size()) +
              " voxels + " + std::to_string(inner_attrs_.size()) + " inner nodes)");
}

std::string SparseVoxelOctree::check_structure() {
  const int depth = grid_.depth;
  const uint64_t voxels = leaf_attrs_.size(), count = nodes_.size();
  level_offsets_.clear();
  if (inner_attrs_.size() != nodes_.size()) return "inner attribute count differs from node count";
  if (depth == 0) {
    if (count != 0) return "a depth-0 octree has no nodes (found " + std::to_string(count) + ")";
    if (voxels > 1) return "a depth-0 grid holds at most one voxel (found " + std::to_string(voxels) + ")";
    level_offsets_ = {0};
    return {};
  }
  if (count == 0) return "no root node";
  std::vector<uint32_t> offsets{0};
  uint64_t begin = 0, end = 1, leaves = 0;
  for (int l = 0; l < depth; ++l) {
    if (end > count)
      return "level " + std::to_string(l) + " needs nodes up to " + std::to_string(end) + " but there are " +
             std::to_string(count);
    const bool last = l == depth - 1;
    uint64_t running = last ? 0 : end;
    for (uint64_t j = begin; j < end; ++j) {
      const SvoNode& n = nodes_[j];
      if (n.mask > 0xFFu) return "node " + std::to_string(j) + ": child mask " + std::to_string(n.mask) + " has bits above 7";
      if (n.mask == 0 && !(j == 0 && voxels == 0 && count == 1))
        return "node " + std::to_string(j) + ": empty child mask (only the root of an empty tree may have one)";
      if (n.first_child != running)
        return "node " + std::to_string(j) + ": first child " + std::to_string(n.first_child) + ", expected " +
               std::to_string(running) + " (children must follow in breadth-first order, increasing)";
      running += static_cast<uint64_t>(std::popcount(n.mask));
    }
    offsets.push_back(static_cast<uint32_t>(end));
    if (last) {
      leaves = running;
    } else {
      begin = end;
      end = running;
    }
  }
  if (end != count)
    return "node count " + std::to_string(count) + " but the tree has " + std::to_string(end) + " nodes";
  if (leaves != voxels)
    return "the tree has " + std::to_string(leaves) + " leaves but " + std::to_string(voxels) + " voxel attributes";
  level_offsets_ = std::move(offsets);
  return {};
}

VoxelSet SparseVoxelOctree::level_set(int level) const {
  const int depth = grid_.depth;
  if (level < 0 || level > depth)
    throw Error("svo: level " + std::to_string(level) + " out of range 0.." + std::to_string(depth));
  VoxelSet out;
  out.grid = grid_;
  out.grid.depth = level;
  if (leaf_attrs_.empty()) return out;
  if (depth == 0) {
    out.codes = {0};
    out.attrs = leaf_attrs_;
    return out;
  }
  std::vector<uint64_t> codes{0}, next;
  for (int l = 0; l < level; ++l) {
    next.clear();
    const uint32_t base = level_offsets_[static_cast<size_t>(l)];
    for (size_t j = 0; j < codes.size(); ++j) {
      const uint32_t mask = nodes_[base + j].mask;
      for (uint32_t k = 0; k < 8; ++k)
        if ((mask >> k) & 1u) next.push_back(codes[j] << 3 | k);
    }
    codes.swap(next);
  }
  out.codes = std::move(codes);
  if (level == depth) {
    out.attrs = leaf_attrs_;
  } else {
    const uint32_t base = level_offsets_[static_cast<size_t>(level)];
    out.attrs.assign(inner_attrs_.begin() + base, inner_attrs_.begin() + base + static_cast<ptrdiff_t>(out.codes.size()));
  }
  return out;
}

}  // namespace specula
