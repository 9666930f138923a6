/// \file math.h
/// Small vector / matrix / bounding-box types used everywhere in specula.
/// Conventions: right-handed, y up, cameras look down -z, metres, linear RGB.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace specula {

inline constexpr float kInf = std::numeric_limits<float>::infinity();
inline constexpr float kPi = 3.14159265358979323846f;

struct Vec2 {
  float x = 0, y = 0;
};

struct Vec3 {
  float x = 0, y = 0, z = 0;

  constexpr Vec3() = default;
  constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
  constexpr explicit Vec3(float s) : x(s), y(s), z(s) {}

  constexpr float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  constexpr float& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }

  constexpr Vec3 operator-() const { return {-x, -y, -z}; }
  constexpr Vec3& operator+=(const Vec3& o) { x += o.x; y += o.y; z += o.z; return *this; }
  constexpr Vec3& operator-=(const Vec3& o) { x -= o.x; y -= o.y; z -= o.z; return *this; }
  constexpr Vec3& operator*=(const Vec3& o) { x *= o.x; y *= o.y; z *= o.z; return *this; }
  constexpr Vec3& operator*=(float s) { x *= s; y *= s; z *= s; return *this; }
  constexpr bool operator==(const Vec3&) const = default;
};

constexpr Vec3 operator+(Vec3 a, const Vec3& b) { return a += b; }
constexpr Vec3 operator-(Vec3 a, const Vec3& b) { return a -= b; }
constexpr Vec3 operator*(Vec3 a, const Vec3& b) { return a *= b; }
constexpr Vec3 operator*(Vec3 a, float s) { return a *= s; }
constexpr Vec3 operator*(float s, Vec3 a) { return a *= s; }
constexpr Vec3 operator/(const Vec3& a, float s) { return a * (1.0f / s); }
constexpr Vec3 operator/(const Vec3& a, const Vec3& b) { return {a.x / b.x, a.y / b.y, a.z / b.z}; }

constexpr float dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
constexpr Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float length(const Vec3& a) { return std::sqrt(dot(a, a)); }
/// Normalizes \p a; returns the zero vector for a zero (or non-finite) input instead of NaN.
inline Vec3 normalize(const Vec3& a) {
  const float len = length(a);
  return (len > 0.0f && std::isfinite(len)) ? a * (1.0f / len) : Vec3{};
}
constexpr Vec3 min(const Vec3& a, const Vec3& b) {
  return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
constexpr Vec3 max(const Vec3& a, const Vec3& b) {
  return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
inline Vec3 abs(const Vec3& a) { return {std::fabs(a.x), std::fabs(a.y), std::fabs(a.z)}; }
constexpr float max_component(const Vec3& a) { return std::max(a.x, std::max(a.y, a.z)); }
constexpr float min_component(const Vec3& a) { return std::min(a.x, std::min(a.y, a.z)); }
inline bool is_finite(const Vec3& a) {
  return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}
inline Vec3 exp(const Vec3& a) { return {std::exp(a.x), std::exp(a.y), std::exp(a.z)}; }
constexpr Vec3 lerp(const Vec3& a, const Vec3& b, float t) { return a * (1.0f - t) + b * t; }
/// Mirror reflection of incoming direction \p d about normal \p n (n unit length).
constexpr Vec3 reflect(const Vec3& d, const Vec3& n) { return d - n * (2.0f * dot(d, n)); }
constexpr float luminance(const Vec3& c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

/// Builds an orthonormal basis (t, b) around unit vector n (Duff et al. 2017, "Building an
/// Orthonormal Basis, Revisited").
inline void orthonormal_basis(const Vec3& n, Vec3& t, Vec3& b) {
  const float sign = std::copysign(1.0f, n.z);
  const float a = -1.0f / (sign + n.z);
  const float bb = n.x * n.y * a;
  t = {1.0f + sign * n.x * n.x * a, sign * bb, -sign * n.x};
  b = {bb, sign + n.y * n.y * a, -n.y};
}

/// Axis-aligned bounding box. Default constructed boxes are empty (min = +inf, max = -inf).
struct Aabb {
  Vec3 min{kInf, kInf, kInf};
  Vec3 max{-kInf, -kInf, -kInf};

  constexpr void grow(const Vec3& p) { min = specula::min(min, p); max = specula::max(max, p); }
  constexpr void grow(const Aabb& b) { min = specula::min(min, b.min); max = specula::max(max, b.max); }
  constexpr bool empty() const { return min.x > max.x || min.y > max.y || min.z > max.z; }
  constexpr Vec3 extent() const { return max - min; }
  constexpr Vec3 center() const { return (min + max) * 0.5f; }
  /// Surface area; 0 for an empty box.
  constexpr float area() const {
    if (empty()) return 0.0f;
    const Vec3 e = extent();
    return 2.0f * (e.x * e.y + e.y * e.z + e.z * e.x);
  }
  constexpr int largest_axis() const {
    const Vec3 e = extent();
    return (e.x >= e.y && e.x >= e.z) ? 0 : (e.y >= e.z ? 1 : 2);
  }
};

/// Row-major 4x4 affine transform (points are column vectors: p' = M p).
struct Mat4 {
  std::array<float, 16> m{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

  static Mat4 identity() { return {}; }
  static Mat4 translate(const Vec3& t) {
    Mat4 r;
    r.m[3] = t.x; r.m[7] = t.y; r.m[11] = t.z;
    return r;
  }
  static Mat4 scale(const Vec3& s) {
    Mat4 r;
    r.m[0] = s.x; r.m[5] = s.y; r.m[10] = s.z;
    return r;
  }
  /// Rotation about unit \p axis by \p radians (Rodrigues).
  static Mat4 rotate(const Vec3& axis, float radians) {
    const Vec3 a = normalize(axis);
    const float c = std::cos(radians), s = std::sin(radians), t = 1.0f - c;
    Mat4 r;
    r.m = {t * a.x * a.x + c,       t * a.x * a.y - s * a.z, t * a.x * a.z + s * a.y, 0,
           t * a.x * a.y + s * a.z, t * a.y * a.y + c,       t * a.y * a.z - s * a.x, 0,
           t * a.x * a.z - s * a.y, t * a.y * a.z + s * a.x, t * a.z * a.z + c,       0,
           0, 0, 0, 1};
    return r;
  }
  /// Rotation from a unit quaternion (x, y, z, w), as glTF stores it.
  static Mat4 from_quaternion(float x, float y, float z, float w) {
    Mat4 r;
    r.m = {1 - 2 * (y * y + z * z), 2 * (x * y - z * w),     2 * (x * z + y * w),     0,
           2 * (x * y + z * w),     1 - 2 * (x * x + z * z), 2 * (y * z - x * w),     0,
           2 * (x * z - y * w),     2 * (y * z + x * w),     1 - 2 * (x * x + y * y), 0,
           0, 0, 0, 1};
    return r;
  }

  Mat4 operator*(const Mat4& o) const {
    Mat4 r;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        float s = 0;
        for (int k = 0; k < 4; ++k) s += m[i * 4 + k] * o.m[k * 4 + j];
        r.m[i * 4 + j] = s;
      }
    return r;
  }
  Vec3 transform_point(const Vec3& p) const {
    return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3], m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
            m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
  }
  Vec3 transform_vector(const Vec3& v) const {
    return {m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
            m[8] * v.x + m[9] * v.y + m[10] * v.z};
  }
  /// Transforms a normal by the inverse transpose of the upper 3x3. With rows r0..r2 the
  /// cofactor matrix has rows r1 x r2, r2 x r0, r0 x r1 and equals det * inverse-transpose;
  /// its magnitude is irrelevant because callers normalize, but its sign is not: a mirroring
  /// transform (det < 0) must still map an outward normal to the outward side.
  Vec3 transform_normal(const Vec3& n) const {
    const Vec3 r0{m[0], m[1], m[2]}, r1{m[4], m[5], m[6]}, r2{m[8], m[9], m[10]};
    const Vec3 c0 = cross(r1, r2);
    const Vec3 w{dot(c0, n), dot(cross(r2, r0), n), dot(cross(r0, r1), n)};
    return dot(r0, c0) < 0.0f ? -w : w;
  }
};

}  // namespace specula
