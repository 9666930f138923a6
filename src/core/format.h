// Small text-formatting helpers shared by the library and the CLI.
#pragma once

#include <cstdint>
#include <string>

namespace specula {

/// 69451 -> "69,451" (for counts in messages and reports).
inline std::string with_thousands(uint64_t n) {
  const std::string digits = std::to_string(n);
  std::string out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out.push_back(',');
    out.push_back(digits[i]);
  }
  return out;
}

}  // namespace specula
