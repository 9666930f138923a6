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
#include <bit>
#include <cmath>
#include <string>
#include <vector>

#include "specula/error.h"
#include "specula/svo.h"
#include "specula/timer.h"
#include "voxel/voxel_brute.h"

namespace specula {

namespace {

/// Averaged attributes of one inner node from its children (weights = voxel counts).
/// \p child_half is the children's half side in world units.
VoxelAttributes average_children(const VoxelAttributes* const* attrs, const uint32_t* weights, const int* slots, int n,
                                 float child_half) {
  VoxelAttributes out;
  Vec3 nsum, csum;
  float refl = 0.0f, transp = 0.0f, ior = 0.0f, wsum = 0.0f;
  int heaviest = 0;
  for (int i = 0; i < n; ++i) {
    const float w = static_cast<float>(weights[i]);
    const VoxelAttributes& a = *attrs[i];
    nsum += a.normal * w;
    csum += a.colour * w;
    refl += a.reflectivity * w;
    transp += a.transparency * w;
    ior += a.ior * w;
    wsum += w;
    if (weights[i] > weights[heaviest]) heaviest = i;
  }
  const float inv = 1.0f / wsum;
  out.colour = csum * inv;
  out.reflectivity = refl * inv;
  out.transparency = transp * inv;
  out.ior = ior * inv;
  out.material = attrs[heaviest]->material;
  Vec3 nrm = normalize(nsum);
  if (nrm == Vec3{}) nrm = normalize(attrs[heaviest]->normal);
  if (nrm == Vec3{}) nrm = Vec3{0.0f, 0.0f, 1.0f};
  out.normal = nrm;

  // Conservative contours: bound dot(n, p - C) over each child's cube intersected with its
  // slab. Two valid bounds, intersected: the child cube alone (h |n|_1), and the child slab
  // after writing n = a n_c + r: a [lo_c, hi_c] + [-h |r|_1, h |r|_1].
  const float l1n = std::fabs(nrm.x) + std::fabs(nrm.y) + std::fabs(nrm.z);
  float lo = kInf, hi = -kInf;
  for (int i = 0; i < n; ++i) {
    const VoxelAttributes& a = *attrs[i];
    const Vec3 delta{(slots[i] & 1) ? child_half : -child_half, (slots[i] & 2) ? child_half : -child_half,
                     (slots[i] & 4) ? child_half : -child_half};
    const float offs = dot(nrm, delta);
    const float cube = child_half * l1n;
    float clo = -cube, chi = cube;
    const float nn = dot(a.normal, a.normal);
    if (nn > 0.0f) {
      const float k = dot(nrm, a.normal) / nn;
      const Vec3 r = nrm - a.normal * k;
      const float rb = child_half * (std::fabs(r.x) + std::fabs(r.y) + std::fabs(r.z));
      const float slo = (k >= 0.0f ? k * a.contour_lo : k * a.contour_hi) - rb;
      const float shi = (k >= 0.0f ? k * a.contour_hi : k * a.contour_lo) + rb;
      if (std::max(clo, slo) <= std::min(chi, shi)) {
        clo = std::max(clo, slo);
        chi = std::min(chi, shi);
      }
    }
    lo = std::min(lo, offs + clo);
    hi = std::max(hi, offs + chi);
  }
  const float pad = 8e-6f * child_half;  // covers the rounding of the sums above
  out.contour_lo = lo - pad;
  out.contour_hi = hi + pad;
  return out;
}

}  // namespace

SparseVoxelOctree SparseVoxelOctree::build(const VoxelSet& set, const VoxelTracerOptions& options, SvoInfo* info) {
  return build_from(set, nullptr, options, info, Timer());
}

SparseVoxelOctree SparseVoxelOctree::build(VoxelSet&& set, const VoxelTracerOptions& options, SvoInfo* info) {
  const Timer timer;
  std::vector<VoxelAttributes> attrs;
  if (!set.attrs.empty()) {
    voxel::validate_set(set, "svo");  // with its attributes, before they move
    attrs.swap(set.attrs);
  }
  return build_from(set, attrs.empty() ? nullptr : &attrs, options, info, timer);
}

SparseVoxelOctree SparseVoxelOctree::build_from(const VoxelSet& set, std::vector<VoxelAttributes>* steal,
                                                const VoxelTracerOptions& options, SvoInfo* info,
                                                const Timer& timer) {
  SparseVoxelOctree svo;
  if (steal) {  // validated by the caller, attributes included
    svo.leaf_attrs_ = std::move(*steal);
  } else {
    voxel::validate_set(set, "svo");
    svo.leaf_attrs_ = voxel::attributes_or_default(set);
  }
  svo.grid_ = set.grid;
  svo.mode_ = options.mode;
  svo.set_lod(options.lod);
  const int depth = set.grid.depth;
  if (depth == 0) {
    svo.level_offsets_ = {0};
    if (info) *info = svo.info(), info->build_ms = timer.ms();
    return svo;
  }

  // Codes and masks of the nodes of every level 0..depth-1, bottom-up.
  std::vector<std::vector<uint64_t>> codes(static_cast<size_t>(depth));
  std::vector<std::vector<uint8_t>> masks(static_cast<size_t>(depth));
  const std::vector<uint64_t>* below = &set.codes;
  for (int l = depth - 1; l >= 0; --l) {
    auto& c = codes[static_cast<size_t>(l)];
    auto& m = masks[static_cast<size_t>(l)];
    for (const uint64_t code : *below) {
      const uint64_t parent = code >> 3;
      if (c.empty() || c.back() != parent) {
        c.push_back(parent);
        m.push_back(0);
      }
      m.back() = static_cast<uint8_t>(m.back() | (1u << (code & 7u)));
    }
    below = &c;
  }
  if (set.codes.empty()) {  // an empty tree is a root without children
    codes[0] = {0};
    masks[0] = {0};
  }

  // Breadth-first layout.
  svo.level_offsets_.assign(static_cast<size_t>(depth) + 1, 0);
  for (int l = 0; l < depth; ++l)
    svo.level_offsets_[static_cast<size_t>(l) + 1] =
        svo.level_offsets_[static_cast<size_t>(l)] + static_cast<uint32_t>(codes[static_cast<size_t>(l)].size());
  svo.nodes_.resize(svo.level_offsets_.back());
  for (int l = 0; l < depth; ++l) {
    uint32_t running = l + 1 < depth ? svo.level_offsets_[static_cast<size_t>(l) + 1] : 0;
    const auto& m = masks[static_cast<size_t>(l)];
    const uint32_t base = svo.level_offsets_[static_cast<size_t>(l)];
    for (size_t j = 0; j < m.size(); ++j) {
      svo.nodes_[base + j] = SvoNode{running, m[j]};
      running += static_cast<uint32_t>(std::popcount(static_cast<unsigned>(m[j])));
    }
  }
  codes.clear();
  masks.clear();

  // Level-of-detail attributes, bottom-up; weights = voxel counts below each node.
  svo.inner_attrs_.resize(svo.nodes_.size());
  std::vector<uint32_t> counts(svo.nodes_.size(), 0);
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  for (int l = depth - 1; l >= 0; --l) {
    const bool leaf_children = l == depth - 1;
    const float child_half = 0.25f * set.grid.side / static_cast<float>(1u << l);
    const uint32_t begin = svo.level_offsets_[static_cast<size_t>(l)], end = svo.level_offsets_[static_cast<size_t>(l) + 1];
    const auto work = [&](const tbb::blocked_range<uint32_t>& range) {
      for (uint32_t i = range.begin(); i != range.end(); ++i) {
        const SvoNode& node = svo.nodes_[i];
        if (node.mask == 0) continue;  // empty root
        const VoxelAttributes* attrs[8];
        uint32_t weights[8];
        int slots[8];
        int n = 0;
        uint32_t total = 0;
        for (int k = 0; k < 8; ++k) {
          if (!((node.mask >> k) & 1u)) continue;
          const uint32_t c = node.first_child + static_cast<uint32_t>(n);
          attrs[n] = leaf_children ? &svo.leaf_attrs_[c] : &svo.inner_attrs_[c];
          weights[n] = leaf_children ? 1u : counts[c];
          slots[n] = k;
          total += weights[n];
          ++n;
        }
        counts[i] = total;
        svo.inner_attrs_[i] = average_children(attrs, weights, slots, n, child_half);
      }
    };
    if (options.threads == 1 || end - begin < 4096) {
      work(tbb::blocked_range<uint32_t>(begin, end));
    } else {
      arena.execute([&] { tbb::parallel_for(tbb::blocked_range<uint32_t>(begin, end, 1024), work); });
    }
  }
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
