/// \file exp_lanes.h
/// std::exp of many floats at once, with std::exp's bits (internal to src/render; tested in
/// tests/lighting_test.cpp). The Whitted integrator's Beer-Lambert attenuation takes three
/// exponentials per ray segment inside an absorbing medium; called one by one they were ~3% of
/// a pool water frame (the library call, and its latency chain in the shading loop).
#pragma once

#include <cstddef>

namespace specula::render {

/// Replaces each of the \p n floats at \p x by std::exp of it, bit for bit.
///
/// How the bits are kept: on x86-64 with AVX2 and FMA, glibc's expf is its FMA variant
/// (the ifunc picks it on exactly those CPUs). For arguments of magnitude below 80 that variant
/// is a fixed sequence of IEEE double operations (a scaled argument split with a rounding shift,
/// a 32-entry table of 2^(i/32), a cubic polynomial, fused multiply-adds where it fuses them,
/// and one rounding to float); those are done here four lanes at a time, the same operations
/// on the same numbers. Every other argument (|x| >= 80, infinities, NaN), every CPU without
/// AVX2 and FMA, and every non-glibc build call std::exp itself.
void exp_in_place(float* x, size_t n);

/// Whether exp_in_place() uses its SIMD path on this CPU (else it calls std::exp per float).
bool exp_lanes_simd();

}  // namespace specula::render
