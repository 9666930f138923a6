#include "core/memory.h"

#include <cstdint>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace specula {

void advise_huge_pages(const void* p, std::size_t bytes) noexcept {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr std::uintptr_t kHuge = std::uintptr_t{2} << 20;
  const auto begin = reinterpret_cast<std::uintptr_t>(p);
  if (p == nullptr || bytes < kHuge || begin > UINTPTR_MAX - bytes) return;
  const std::uintptr_t lo = (begin + kHuge - 1) & ~(kHuge - 1), hi = (begin + bytes) & ~(kHuge - 1);
  if (hi <= lo) return;
  // Advice only: an older kernel or one built without THP answers EINVAL, which changes nothing.
  // (The aligned start as an offset from p: no integer-to-pointer cast.)
  void* const start = const_cast<char*>(static_cast<const char*>(p)) + (lo - begin);
  (void)madvise(start, hi - lo, MADV_HUGEPAGE);
#else
  (void)p;
  (void)bytes;
#endif
}

}  // namespace specula
