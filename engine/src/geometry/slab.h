// SPDX-License-Identifier: Apache-2.0
// The ray/box slab test of every traversal.
#pragma once

#include "geometry/float32.h"
#include "geometry/ray.h"

#include <limits>
#include <utility>

namespace clastrace::engine::geometry {

inline constexpr double kUnitRoundoff = std::numeric_limits<double>::epsilon() * 0.5;
// Ize 2013: scaling the far distance by 1 + 2*gamma(3) makes the double slab test
// conservative: a box never culls a point of the ray that lies in it.
inline constexpr double kConservativeFarScale =
    1.0 + 2.0 * (3.0 * kUnitRoundoff) / (1.0 - 3.0 * kUnitRoundoff);

// Whether the ray meets [lo, hi] within [r.tmin, tmax]; `*entry` is where it enters
// (r.tmin when it starts inside). Robust: the far distances are scaled as above (what
// culling needs); without it the test answers for the rounded distances. A zero direction
// component tests the origin against the slab; a NaN distance (NaN origin, infinite origin
// against an infinite bound) misses.
template <bool Robust>
inline bool slab_test(const PreparedRay& r, const float lo[3], const float hi[3], double tmax,
                      double* entry) {
    // The float32 mode is always conservative (its widening is what it rounds by).
    if (r.mode == TraversalMode::kFloat32) return slab_test_float32(r, lo, hi, tmax, entry);
    double t_near = r.tmin, t_far = tmax;
    // One verdict at the end instead of a branch per axis: traversals run this on every
    // child box, where early exits mispredict. An interval that ends before it starts only
    // happens when the final test fails too, so `ok` only adds the NaN and zero-direction
    // misses.
    bool ok = true;
    for (int a = 0; a < 3; ++a) {
        if (r.d[a] == 0.0) {
            ok &= (r.o[a] >= lo[a]) & (r.o[a] <= hi[a]);
            continue;
        }
        double t0 = (double(lo[a]) - r.o[a]) * r.inv[a], t1 = (double(hi[a]) - r.o[a]) * r.inv[a];
        if (t0 > t1) std::swap(t0, t1);
        if constexpr (Robust) t1 *= kConservativeFarScale;
        ok &= t0 <= t1;  // false when either is NaN
        t_near = t0 > t_near ? t0 : t_near;
        t_far = t1 < t_far ? t1 : t_far;
    }
    *entry = t_near;
    return ok & (t_near <= t_far);
}

}  // namespace clastrace::engine::geometry
