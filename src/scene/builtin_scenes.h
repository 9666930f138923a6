/// \file builtin_scenes.h
/// Constructors of the built-in scenes (internal; see make_builtin_scene in load.h).
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "specula/load.h"
#include "specula/scene.h"

namespace specula::builtin {

/// Stanford bunny half submerged in a tiled pool; cameras overview, water, bunny, parallel.
Scene make_pool(const LoadOptions& options);
inline constexpr const char* kBunnyFile = "stanford-bunny.obj";
/// make_pool with an explicit bunny file; an empty path gives the procedural stand-in and one
/// warning through options.warn (used by make_pool and by tests).
Scene make_pool_with_bunny(const LoadOptions& options, const std::filesystem::path& bunny_path);
/// Seed 001's test space: glass panes in a solid frame, open front, semi-solid core, RGB lights.
Scene make_glassbox(const LoadOptions& options);
/// Cornell box with a mirror block, a glass sphere and a small spherical ceiling light.
Scene make_cornell(const LoadOptions& options);

/// Procedural town in the spirit of seed 002: streets on a grid, buildings with window grids
/// and glass shop windows, a canal with a bridge, an elevated road (underpass), a plaza, a wet
/// mirror-like road; one MeshRange per zone; cameras street, underpass, bridge, plaza.
/// Deterministic: the same triangles on every machine.
inline constexpr uint64_t kCityDefaultTriangles = 600000;
inline constexpr uint64_t kCityMinTriangles = 10000;
inline constexpr uint64_t kCityMaxTriangles = 20000000;
/// The default city (about kCityDefaultTriangles triangles).
Scene make_city(const LoadOptions& options);
/// A city of about \p target triangles; throws specula::Error outside [kCityMinTriangles,
/// kCityMaxTriangles].
Scene make_city_with_triangles(uint64_t target);
/// "city" -> the default size, "city:N" -> N; nullopt when \p spec is not a city name; throws
/// specula::Error naming the spec when N is not a whole number in range.
std::optional<uint64_t> parse_city_spec(const std::string& spec);

}  // namespace specula::builtin
