// Shared helpers for the test suite.
#pragma once

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>

#include "specula/error.h"

namespace specula::test {

/// Folder of the shared test meshes: $SPECULA_DATA if set, else ../shared/data/meshes beside
/// the source tree. Empty path when neither exists.
inline std::filesystem::path shared_mesh_dir() {
  if (const char* env = std::getenv("SPECULA_DATA"); env && *env && std::filesystem::is_directory(env))
    return env;
  const std::filesystem::path p = std::filesystem::path(SPECULA_SOURCE_DIR) / ".." / "shared" / "data" / "meshes";
  return std::filesystem::is_directory(p) ? p : std::filesystem::path{};
}

/// Full path of a shared mesh, or empty when absent.
inline std::filesystem::path shared_mesh(const std::string& file) {
  const auto dir = shared_mesh_dir();
  if (dir.empty()) return {};
  const auto p = dir / file;
  return std::filesystem::exists(p) ? p : std::filesystem::path{};
}

/// The shipped meshes every oracle test runs on.
inline const char* const kSharedMeshes[] = {"stanford-bunny.obj", "teapot.obj", "spot.obj", "cow.obj",
                                            "fandisk.obj", "homer.obj", "rocker-arm.obj"};

/// Test name of a parameterised test over kSharedMeshes: the file name without extension, '-'
/// as '_' ("stanford-bunny.obj" -> "stanford_bunny").
inline std::string mesh_param_name(const ::testing::TestParamInfo<const char*>& param) {
  std::string s = param.param;
  s = s.substr(0, s.find('.'));
  for (char& c : s)
    if (c == '-') c = '_';
  return s;
}

/// A fresh, empty temporary folder for one test (removed by the caller's fixture or left in /tmp).
inline std::filesystem::path temp_dir(const std::string& tag) {
  auto d = std::filesystem::temp_directory_path() /
           ("specula-test-" + tag + "-" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
            "-" + std::to_string(reinterpret_cast<uintptr_t>(&tag)));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

/// The message of the specula::Error that \p f throws, or "(no specula::Error thrown)".
inline std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no specula::Error thrown)";
}

}  // namespace specula::test

/// Skips the current test with a message naming the file and where it was searched.
#define SPECULA_REQUIRE_MESH(var, file)                                                          \
  const std::filesystem::path var = ::specula::test::shared_mesh(file);                          \
  if (var.empty())                                                                                \
  GTEST_SKIP() << "shared mesh " << (file) << " not found (set SPECULA_DATA or place ../shared/data/meshes beside the source tree)"
