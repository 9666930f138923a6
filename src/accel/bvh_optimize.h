// Optimisation of a built binary BVH by subtree reinsertion (owner: accel).
#pragma once

#include <cstdint>
#include <span>

#include "specula/bvh.h"

namespace specula::accel {

/// What one reinsertion pass did.
struct ReinsertionStats {
  int rounds = 0;          ///< rounds run (each reinserts the worst-placed subtrees once)
  uint64_t moves = 0;      ///< subtrees that moved to a cheaper place
  double cost_before = 0;  ///< sum of the interior nodes' half areas, before
  double cost_after = 0;   ///< and after (leaves are unchanged, so this is what the pass lowers)
};

/// Lowers the SAH cost of the binary tree \p nodes (the builder's layout: node 0 the root, node
/// 1 padding, an interior node's children at left_first and left_first + 1, a leaf's triangles
/// at prim_ids[left_first .. left_first + count)) by reinsertion (Bittner, Hapala, Havran 2013,
/// "Fast Insertion-Based Optimization of Bounding Volume Hierarchies"): subtrees whose parent
/// boxes are large for what they hold are taken out and put back as the sibling of the node
/// where they add the least surface area to the tree (a best-first search with a lower bound,
/// so the place found is the cheapest of all). Leaves keep their triangles; the tree keeps its
/// node count and never gets deeper than \p max_depth (nor than it was, if deeper). The result is
/// written back in the same layout, numbered depth first, with every subtree's triangles
/// contiguous in \p prim_ids (which is permuted accordingly). Serial and deterministic: the same
/// input gives the same tree. The cost never rises.
ReinsertionStats optimize_by_reinsertion(std::span<BvhNode> nodes, std::span<uint32_t> prim_ids, uint32_t max_depth);

}  // namespace specula::accel
