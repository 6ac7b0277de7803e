// SPDX-License-Identifier: Apache-2.0
// The box tests of TraversalMode::kFloat32: the arithmetic of a float32 hardware pipeline on
// the float copy of a prepared ray (ray.h); slab.h dispatches here by the ray's mode. (The
// float triangle test sits beside the double one in triangle.h.)
#pragma once

#include "geometry/ray.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace clastrace::engine::geometry {

// Each slab distance (p - o) * (1 / d) carries three float roundings, a relative error of at
// most gamma(3) = 3u / (1 - 3u) < 4 * FLT_EPSILON / 2. Widening both ends by 4 ulps of
// themselves (relative 4 * FLT_EPSILON, computed in double so the widening itself does not
// round back) contains the exact interval: a box never culls a point of the float ray inside
// it, so never a triangle the float triangle test finds.
inline constexpr double kFloat32SlabWiden = 4.0 * std::numeric_limits<float>::epsilon();

// Whether the float ray meets [lo, hi] within [r.tmin, tmax]; `*entry` as slab_test's. A zero
// direction component tests the origin against the slab; a NaN distance misses.
inline bool slab_test_float32(const PreparedRay& r, const float lo[3], const float hi[3],
                              double tmax, double* entry) {
    double t_near = r.tmin, t_far = tmax;
    bool ok = true;
    for (int a = 0; a < 3; ++a) {
        if (r.fd[a] == 0.0f) {
            ok &= (r.fo[a] >= lo[a]) & (r.fo[a] <= hi[a]);
            continue;
        }
        float f0 = (lo[a] - r.fo[a]) * r.finv[a], f1 = (hi[a] - r.fo[a]) * r.finv[a];
        if (f0 > f1) std::swap(f0, f1);
        const double t0 = double(f0) - std::fabs(double(f0)) * kFloat32SlabWiden;
        const double t1 = double(f1) + std::fabs(double(f1)) * kFloat32SlabWiden;
        ok &= t0 <= t1;  // false when either is NaN
        t_near = t0 > t_near ? t0 : t_near;
        t_far = t1 < t_far ? t1 : t_far;
    }
    *entry = t_near;
    return ok & (t_near <= t_far);
}

// The ray check's intersection shader for an AABB primitive (capture/shaders/ray_check.rint)
// as the driver runs it: a plain float slab test on the object-space float ray, the hit at
// max(entry, tmin) when that is not past the exit. No widening: the shader has none. NaN
// distances miss (GLSL leaves min/max of NaN undefined; a driver's NaN box never hit in the
// captured traces).
inline bool aabb_shader_float32(const PreparedRay& r, const float lo[3], const float hi[3],
                                double* t_hit) {
    float entry = -std::numeric_limits<float>::infinity();
    float exit = std::numeric_limits<float>::infinity();
    for (int a = 0; a < 3; ++a) {
        const float t0 = (lo[a] - r.fo[a]) * r.finv[a], t1 = (hi[a] - r.fo[a]) * r.finv[a];
        if (std::isnan(t0) || std::isnan(t1)) return false;
        entry = std::max(entry, std::min(t0, t1));
        exit = std::min(exit, std::max(t0, t1));
    }
    const float t = std::max(entry, float(r.tmin));
    if (!(t <= exit)) return false;
    *t_hit = t;
    return true;
}

}  // namespace clastrace::engine::geometry
