#include "core/memory.h"

#include <algorithm>
#include <cstdint>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace specula {

void prepare_for_writes(const void* p, std::size_t bytes) noexcept {
#if defined(__linux__)
  constexpr std::uintptr_t kHuge = std::uintptr_t{2} << 20, kPage = 4096;
  const auto begin = reinterpret_cast<std::uintptr_t>(p);
  if (p == nullptr || bytes == 0 || begin > UINTPTR_MAX - bytes - kHuge) return;
  const std::uintptr_t end = begin + bytes;
  const std::uintptr_t lo = (begin + kHuge - 1) & ~(kHuge - 1), hi = end & ~(kHuge - 1);
  // Addresses as offsets from p (no integer-to-pointer casts). Advice only: a kernel without
  // THP or MADV_POPULATE_WRITE (before Linux 5.14) answers EINVAL, which changes nothing.
  char* const base = const_cast<char*>(static_cast<const char*>(p));
#if defined(MADV_HUGEPAGE)
  if (hi > lo) (void)madvise(base + (lo - begin), hi - lo, MADV_HUGEPAGE);
#endif
#if defined(MADV_POPULATE_WRITE)
  // The head: from p's page to the first huge page (or the end), at most 2 MiB.
  const std::uintptr_t head_lo = begin & ~(kPage - 1), head_hi = std::min(lo, (end + kPage - 1) & ~(kPage - 1));
  if (head_hi > head_lo) (void)madvise(base - (begin - head_lo), head_hi - head_lo, MADV_POPULATE_WRITE);
#endif
#else
  (void)p;
  (void)bytes;
#endif
}

}  // namespace specula
