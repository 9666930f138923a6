// prepare_for_writes only advises and prefaults: whatever range it gets, memory keeps its
// contents and stays usable (the builders call it on buffers they then fill), and the pages
// it prefaults take no fault when they are written.
#include "core/memory.h"

#include <gtest/gtest.h>
#include <sys/mman.h>
#include <sys/resource.h>

#include <cstdint>
#include <numeric>
#include <vector>

namespace specula {
namespace {

TEST(PrepareForWrites, KeepsContentsForAnyRange) {
  std::vector<uint32_t> v(3u << 20);  // 12 MiB: several whole 2 MiB pages inside
  std::iota(v.begin(), v.end(), 7u);
  const size_t bytes = v.size() * sizeof(uint32_t);
  prepare_for_writes(v.data(), bytes);
  prepare_for_writes(v.data() + 1, bytes - 8);  // unaligned ends
  prepare_for_writes(v.data(), 100);            // a few bytes: only their page
  prepare_for_writes(nullptr, bytes);
  prepare_for_writes(v.data(), SIZE_MAX);       // would wrap the address space: ignored
  for (size_t i = 0; i < v.size(); i += 4099) ASSERT_EQ(v[i], 7u + i);
  v.back() = 1;  // still writable everywhere
  EXPECT_EQ(v.back(), 1u);
}

TEST(PrepareForWrites, FreshPagesReadAsZeroAfterAdvice) {
  std::vector<uint64_t> v;
  v.reserve(size_t{8} << 20);  // 64 MiB of address space, untouched
  prepare_for_writes(v.data(), v.capacity() * sizeof(uint64_t));
  v.resize(size_t{8} << 20);  // value-initialised: every element 0, then written
  for (size_t i = 0; i < v.size(); i += 511) ASSERT_EQ(v[i], 0u);
  v[v.size() / 2] = 42;
  EXPECT_EQ(v[v.size() / 2], 42u);
}

long minor_faults() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_minflt;
}

TEST(PrepareForWrites, PrefaultedPagesTakeNoFaultWhenWritten) {
  // A fresh anonymous mapping, started 1 MiB past a 2 MiB boundary: its first MiB is the head
  // that is prefaulted 4 KiB page by page, the rest lies in whole huge pages. The faults its
  // writes take are compared with those of a control MiB, mapped the same way but not
  // prefaulted (and kept off huge pages): a sanitizer's shadow memory faults in both.
  constexpr size_t kMiB = size_t{1} << 20;
  const auto map = [] {
    void* const raw = mmap(nullptr, 8 * kMiB, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    return raw == MAP_FAILED ? nullptr : static_cast<char*>(raw);
  };
  char* const base = map();
  char* const control = map();
  ASSERT_NE(base, nullptr);
  ASSERT_NE(control, nullptr);
  const size_t skip = ((2 * kMiB - reinterpret_cast<uintptr_t>(base) % (2 * kMiB)) + kMiB) % (2 * kMiB);
  char* const p = base + skip;
  const bool supported = madvise(base, 4096, MADV_POPULATE_WRITE) == 0;  // Linux >= 5.14
  (void)madvise(control, 8 * kMiB, MADV_NOHUGEPAGE);
  const auto faults_writing = [](char* q) {
    const long before = minor_faults();
    for (size_t i = 0; i < kMiB; i += 4096) q[i] = 1;
    return minor_faults() - before;
  };
  long taken = 0, control_taken = 0;
  if (supported) {
    prepare_for_writes(p, kMiB);  // all head
    taken = faults_writing(p);
    control_taken = faults_writing(control + 4096);
    for (size_t i = 0; i < kMiB; i += 4096) ASSERT_EQ(p[i], 1);
  }
  munmap(base, 8 * kMiB);
  munmap(control, 8 * kMiB);
  if (!supported) GTEST_SKIP() << "this kernel has no MADV_POPULATE_WRITE";
  EXPECT_GE(control_taken, 256) << "the control MiB should fault once per page";
  EXPECT_LT(4 * taken, control_taken) << "writing 256 prefaulted pages took " << taken << " faults, the control "
                                      << control_taken;
}

}  // namespace
}  // namespace specula
