// advise_huge_pages is advice only: whatever range it gets, memory keeps its contents and
// stays usable (the builders call it on buffers they then fill).
#include "core/memory.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <numeric>
#include <vector>

namespace specula {
namespace {

TEST(AdviseHugePages, KeepsContentsForAnyRange) {
  std::vector<uint32_t> v(3u << 20);  // 12 MiB: several whole 2 MiB pages inside
  std::iota(v.begin(), v.end(), 7u);
  const size_t bytes = v.size() * sizeof(uint32_t);
  advise_huge_pages(v.data(), bytes);
  advise_huge_pages(v.data() + 1, bytes - 8);  // unaligned ends
  advise_huge_pages(v.data(), 100);            // under one huge page: nothing to advise
  advise_huge_pages(nullptr, bytes);
  advise_huge_pages(v.data(), SIZE_MAX);       // would wrap the address space: ignored
  for (size_t i = 0; i < v.size(); i += 4099) ASSERT_EQ(v[i], 7u + i);
  v.back() = 1;  // still writable everywhere
  EXPECT_EQ(v.back(), 1u);
}

TEST(AdviseHugePages, FreshPagesReadAsZeroAfterAdvice) {
  std::vector<uint64_t> v;
  v.reserve(size_t{8} << 20);  // 64 MiB of address space, untouched
  advise_huge_pages(v.data(), v.capacity() * sizeof(uint64_t));
  v.resize(size_t{8} << 20);  // value-initialised: every element 0, then written
  for (size_t i = 0; i < v.size(); i += 511) ASSERT_EQ(v[i], 0u);
  v[v.size() / 2] = 42;
  EXPECT_EQ(v[v.size() / 2], 42u);
}

}  // namespace
}  // namespace specula
