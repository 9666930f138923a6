/// \file error.h
/// The one exception type of specula. Messages name the file, the position (line or byte
/// offset) when known, and what was wrong; the CLI prints them and exits non-zero.
#pragma once

#include <stdexcept>
#include <string>

namespace specula {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

/// Convenience: `throw file_error(path, "line 12: face index 7 out of range (3 vertices)")`
/// produces "path: line 12: face index 7 out of range (3 vertices)".
inline Error file_error(const std::string& path, const std::string& what) {
  return Error(path + ": " + what);
}

}  // namespace specula
