// libFuzzer entry point of one target; SPECULA_FUZZ_TARGET (set by fuzz/CMakeLists.txt) names
// its body in fuzz_targets.h. specula::Error is a clean refusal; anything else aborts, so
// libFuzzer saves the input as a crash (sanitizer reports, leaks and hangs it catches itself).
#include <cstdio>
#include <cstdlib>
#include <exception>

#include "fuzz_targets.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    SPECULA_FUZZ_TARGET(std::string_view(reinterpret_cast<const char*>(data), size));
  } catch (const specula::Error&) {
    // Refused with a clear error: the documented outcome for malformed input.
  } catch (const specula::fuzz::Bug& e) {
    std::fprintf(stderr, "specula fuzz: BUG: %s\n", e.what());
    std::abort();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "specula fuzz: BUG: non-specula exception escaped the loader: %s\n", e.what());
    std::abort();
  } catch (...) {
    std::fprintf(stderr, "specula fuzz: BUG: unknown exception escaped the loader\n");
    std::abort();
  }
  return 0;
}
