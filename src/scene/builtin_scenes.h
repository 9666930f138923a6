/// \file builtin_scenes.h
/// Constructors of the built-in scenes (internal; see make_builtin_scene in load.h).
#pragma once

#include <filesystem>

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

}  // namespace specula::builtin
