// Memory helpers shared by the builders (voxelizer, octree, BVH).
#pragma once

#include <cstddef>

namespace specula {

/// Asks the kernel to back the whole 2 MiB pages inside [p, p + bytes) with transparent huge
/// pages when they are first touched (Linux madvise(MADV_HUGEPAGE); a no-op elsewhere, for
/// ranges under 2 MiB, or when the kernel says no). For large output buffers that a build
/// fills once: on a virtual machine every 4 KiB page fault is a trap to the hypervisor, and a
/// 12 MiB voxel set took ~3,000 of them. Contents and addresses are unchanged.
void advise_huge_pages(const void* p, std::size_t bytes) noexcept;

}  // namespace specula
