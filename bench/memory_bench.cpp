// Google Benchmark: what first-touching fresh memory costs on this machine, the reason the
// builders call prepare_for_writes (src/core/memory.h) on their large output buffers.
//   build/release/specula_bench --benchmark_filter=FirstTouch
// Each iteration maps 64 MiB of fresh anonymous memory (2 MiB aligned), writes one byte per
// 4 KiB page and unmaps it: 0 = plain 4 KiB page faults, 1 = the whole range prefaulted first
// by madvise(MADV_POPULATE_WRITE), 2 = advised onto transparent huge pages (MADV_HUGEPAGE),
// 3 = prepare_for_writes itself. On a virtual machine with shadow page tables every 4 KiB page
// table update is a trap to the host; huge pages need one entry per 2 MiB.
#include <benchmark/benchmark.h>
#include <sys/mman.h>

#include <cstdint>

#include "core/memory.h"

namespace {

void BM_FirstTouch(benchmark::State& state) {
  constexpr size_t kBytes = size_t{64} << 20, kHuge = size_t{2} << 20;
  const auto mode = state.range(0);
  for (auto _ : state) {
    void* const raw = mmap(nullptr, kBytes + kHuge, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (raw == MAP_FAILED) {
      state.SkipWithError("mmap failed");
      return;
    }
    char* const base = static_cast<char*>(raw);
    char* const p = base + (kHuge - reinterpret_cast<uintptr_t>(base) % kHuge) % kHuge;
    if (mode == 1) madvise(p, kBytes, MADV_POPULATE_WRITE);
    if (mode == 2) madvise(p, kBytes, MADV_HUGEPAGE);
    if (mode == 3) specula::prepare_for_writes(p, kBytes);
    for (size_t i = 0; i < kBytes; i += 4096) p[i] = 1;
    benchmark::DoNotOptimize(p[kBytes - 1]);
    munmap(raw, kBytes + kHuge);
  }
  // Seconds per 4 KiB page (printed with an SI prefix: 14.5u = 14.5 us).
  state.counters["s_per_page"] = benchmark::Counter(static_cast<double>(kBytes / 4096),
                                                    benchmark::Counter::kIsIterationInvariantRate |
                                                        benchmark::Counter::kInvert);
}
BENCHMARK(BM_FirstTouch)->DenseRange(0, 3)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
