// Shared helpers of the libFuzzer targets (fuzz/README in docs/SECURITY.md).
//
// specula's loaders take paths, so every target writes the fuzz input into a private folder
// (one per process: mkdtemp, removed at exit) under the right file name and calls the public
// loader. A specula::Error is the expected outcome for garbage. Anything else is a bug and
// must crash the target so libFuzzer records it: a sanitizer report, a leak, a hang (libFuzzer's
// -timeout), a broken invariant (fuzz::Bug) or an exception of any other type.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "specula/error.h"
#include "specula/load.h"

namespace specula::fuzz {

/// Separates the files of a multi-file input (OBJ | MTL, glTF | .bin, JSON | OBJ | PLY).
/// A line of its own so that text mutators and the dictionaries can produce it.
inline constexpr std::string_view kSplit = "\n#--8<--\n";

/// Splits \p data at kSplit into at most \p max_parts parts (the last part keeps any further
/// separators).
inline std::vector<std::string_view> split(std::string_view rest, size_t max_parts) {
  std::vector<std::string_view> parts;
  while (parts.size() + 1 < max_parts) {
    const size_t at = rest.find(kSplit);
    if (at == std::string_view::npos) break;
    parts.push_back(rest.substr(0, at));
    rest.remove_prefix(at + kSplit.size());
  }
  parts.push_back(rest);
  return parts;
}

/// The private scratch folder of this process (under $TMPDIR), created on first use and removed
/// at a normal exit (libFuzzer leaves with _Exit: scripts/fuzz.sh points TMPDIR at its scratch).
inline const std::filesystem::path& scratch_dir() {
  static const std::filesystem::path dir = [] {
    std::error_code ec;
    std::filesystem::path base = std::filesystem::temp_directory_path(ec);
    if (ec) base = "/tmp";
    std::string tmpl = (base / "specula-fuzz-XXXXXX").string();
    if (::mkdtemp(tmpl.data()) == nullptr) {
      std::perror("specula fuzz: mkdtemp");
      std::abort();
    }
    std::atexit([] {
      std::error_code ec2;
      std::filesystem::remove_all(scratch_dir(), ec2);
    });
    return std::filesystem::path(tmpl);
  }();
  return dir;
}

/// Writes \p bytes to scratch_dir() / \p name (replacing it) and returns the full path.
inline std::filesystem::path put_file(const std::string& name, std::string_view bytes) {
  const std::filesystem::path p = scratch_dir() / name;
  std::FILE* f = std::fopen(p.c_str(), "wb");
  if (f == nullptr) {
    std::perror(p.c_str());
    std::abort();
  }
  if (!bytes.empty() && std::fwrite(bytes.data(), 1, bytes.size(), f) != bytes.size()) {
    std::perror(p.c_str());
    std::abort();
  }
  std::fclose(f);
  return p;
}

/// Removes scratch_dir() / \p name if present (so a part absent from this input is absent).
inline void drop_file(const std::string& name) {
  std::error_code ec;
  std::filesystem::remove(scratch_dir() / name, ec);
}

/// Load options for fuzzing: warnings are discarded; meshes named by a JSON scene's "data" key
/// are searched only in the scratch folder (plus $SPECULA_DATA and the shared data folder the
/// library always searches).
inline LoadOptions quiet_options() {
  LoadOptions o;
  o.warn = [](const std::string&) {};
  o.data.cli_dir = scratch_dir().string();
  return o;
}

/// A broken invariant found after a successful load (an invalid scene, a tree that does not
/// rewrite identically, ...): a bug, unlike specula::Error which is a clean refusal.
struct Bug : std::logic_error {
  using std::logic_error::logic_error;
};

}  // namespace specula::fuzz
