// Memory helpers shared by the builders (voxelizer, octree, BVH).
#pragma once

#include <cstddef>

namespace specula {

/// Readies [p, p + bytes), memory a build is about to fill, for its first writes (Linux; a
/// no-op elsewhere or when the kernel says no): the whole 2 MiB pages inside the range are
/// advised onto transparent huge pages (madvise MADV_HUGEPAGE: one fault per 2 MiB when
/// first touched), and the 4 KiB pages before the first 2 MiB boundary are faulted in with one
/// call (MADV_POPULATE_WRITE). On a virtual machine every 4 KiB page fault is a trap to the
/// hypervisor (~11 us on ours, BM_FirstTouch): a 12 MiB voxel set took ~3,000 of them, the city's BVH build
/// spent 28% of its time there. Contents and addresses are unchanged.
void prepare_for_writes(const void* p, std::size_t bytes) noexcept;

}  // namespace specula
