// SPDX-License-Identifier: Apache-2.0
// The engine's ray/triangle test, one per traversal mode, both watertight (Woop, Benthin &
// Wald 2013: dimension permutation, shear, edge functions):
// - kDouble: double precision throughout, so that coordinates up to ±FLT_MAX neither
//   overflow nor lose the watertight property;
// - kFloat32: the paper's float version, as a float32 pipeline runs it; where an edge
//   function comes out exactly 0 (the paper's fallback: float cannot tell the sign there)
//   or not finite, the double test answers, so shared edges and vertices stay closed and
//   coordinates beyond float's products (~1e19, ~1e-19) are not lost.
// Edge functions equal to zero count as inside; a triangle whose edge functions are all
// zero (seen edge-on, degenerate) or not finite is missed. Hits lie in the closed interval
// [tmin, tmax]. Facing: kDouble from the triangle's own edges (front_facing), kFloat32 from the
// sign of the float determinant (float_det_front), as hardware decides it.
#pragma once

#include "geometry/ray.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace clastrace::engine::geometry {

struct TriangleHit {
    double t;
    double u, v;  // barycentric weights of p1 and p2
    // How far a float32 evaluation's u, v may sit from these (barycentric_float_error): a
    // tiny triangle seen from far away has float-noise edge functions, u, v then are too.
    double uv_error;
    // Vulkan's facing before any instance flag: front when p0, p1, p2 appear clockwise seen
    // from the ray origin looking along the ray, i.e. dot(d, cross(p1 - p0, p2 - p0)) < 0.
    bool front;
};

// The sign of dot(d, cross(p1 - p0, p2 - p0)) evaluated from the triangle's own edges: it
// depends only on the triangle and the direction, not on where the ray starts (the
// sheared edge functions of the hit test carry the origin's rounding and give the wrong
// winding for nearly edge-on triangles far from the origin).
inline bool front_facing(const double d[3], const float* p0, const float* p1, const float* p2) {
    const double e1[3] = {double(p1[0]) - p0[0], double(p1[1]) - p0[1], double(p1[2]) - p0[2]};
    const double e2[3] = {double(p2[0]) - p0[0], double(p2[1]) - p0[1], double(p2[2]) - p0[2]};
    const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                         e1[0] * e2[1] - e1[1] * e2[0]};
    return d[0] * n[0] + d[1] * n[1] + d[2] * n[2] < 0.0;
}

// Facing in TraversalMode::kFloat32, as a float32 pipeline decides it: from the sign of the
// float determinant (the sum of the sheared edge functions), not from the exact winding. The
// determinant is -dot(d, cross(p1 - p0, p2 - p0)) / |d[kz]| (the permutation is cyclic and
// swaps x, y when d[kz] < 0), so front (dot < 0) is det > 0. For a nearly edge-on triangle
// its rounding can give the other facing than front_facing; the driver reports that one.
inline bool float_det_front(float det) { return det > 0.0f; }

// The error bound of a float evaluation's barycentrics. Shearing rounds each sheared
// coordinate by about 3u of the largest unsheared one (`unsheared`: |vertex - origin|, 4e4 for
// a triangle 4e4 away however small it is); each edge function multiplies two sheared
// coordinates (largest `sheared`), so it is off by about 6u * unsheared * sheared + 2u *
// sheared^2, and u = V / det by four times that over |det|. Rounded up: 16 float epsilons.
// (Chains of two-operand maxima, unrolled: the initializer-list form compiled to a loop over a
// copy in memory, about 60 instructions a hit.)
// `unsheared`, `sheared`: the largest magnitudes (triangle4.h's float32 test has them as such).
inline double barycentric_float_error(double unsheared, double sheared, double det) {
    const double eps = std::numeric_limits<float>::epsilon();
    return 16.0 * eps * (unsheared * sheared + sheared * sheared) / std::fabs(det);
}
inline double barycentric_float_error(const double a[3], const double b[3], const double c[3],
                                      double sheared, double det) {
    double unsheared = 0.0;
#pragma GCC unroll 3
    for (int k = 0; k < 3; ++k)
        unsheared = std::max(std::max(std::max(unsheared, std::fabs(a[k])), std::fabs(b[k])),
                             std::fabs(c[k]));
    return barycentric_float_error(unsheared, sheared, det);
}

// The largest |x| of six sheared coordinates, as std::max({|ax|, ...}) gives it (the same
// two-operand maxima in the same order, without the initializer list's copy).
inline double largest_magnitude(double ax, double ay, double bx, double by, double cx, double cy) {
    return std::max(std::max(std::max(std::max(std::max(std::fabs(ax), std::fabs(ay)),
                                               std::fabs(bx)),
                                      std::fabs(by)),
                             std::fabs(cx)),
                    std::fabs(cy));
}

inline bool intersect_triangle_double(const PreparedRay& r, const float* p0, const float* p1,
                                      const float* p2, double tmax, TriangleHit* hit) {
    double a[3], b[3], c[3];
#pragma GCC unroll 3
    for (int k = 0; k < 3; ++k) {
        a[k] = double(p0[k]) - r.o[k];
        b[k] = double(p1[k]) - r.o[k];
        c[k] = double(p2[k]) - r.o[k];
    }
    const double ax = a[r.kx] - r.sx * a[r.kz], ay = a[r.ky] - r.sy * a[r.kz];
    const double bx = b[r.kx] - r.sx * b[r.kz], by = b[r.ky] - r.sy * b[r.kz];
    const double cx = c[r.kx] - r.sx * c[r.kz], cy = c[r.ky] - r.sy * c[r.kz];
    const double u = cx * by - cy * bx, v = ax * cy - ay * cx, w = bx * ay - by * ax;
    if ((u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0)) return false;
    const double det = u + v + w;
    if (det == 0.0 || !std::isfinite(det)) return false;
    const double t_scaled = u * (r.sz * a[r.kz]) + v * (r.sz * b[r.kz]) + w * (r.sz * c[r.kz]);
    const double t = t_scaled / det;
    if (!(t >= r.tmin && t <= tmax)) return false;
    hit->t = t;
    hit->u = v / det;
    hit->v = w / det;
    hit->uv_error =
        barycentric_float_error(a, b, c, largest_magnitude(ax, ay, bx, by, cx, cy), det);
    hit->front = front_facing(r.d, p0, p1, p2);
    return true;
}

// The paper's float code path: det and t stay float, t = t_scaled * (1 / det).
inline bool intersect_triangle_float32(const PreparedRay& r, const float* p0, const float* p1,
                                       const float* p2, double tmax, TriangleHit* hit) {
    float a[3], b[3], c[3];
    for (int k = 0; k < 3; ++k) {
        a[k] = p0[k] - r.fo[k];
        b[k] = p1[k] - r.fo[k];
        c[k] = p2[k] - r.fo[k];
    }
    const float ax = a[r.kx] - r.fsx * a[r.kz], ay = a[r.ky] - r.fsy * a[r.kz];
    const float bx = b[r.kx] - r.fsx * b[r.kz], by = b[r.ky] - r.fsy * b[r.kz];
    const float cx = c[r.kx] - r.fsx * c[r.kz], cy = c[r.ky] - r.fsy * c[r.kz];
    const float u = cx * by - cy * bx, v = ax * cy - ay * cx, w = bx * ay - by * ax;
    // An edge function exactly 0 (the paper's fallback: float cannot tell its sign; also
    // products below float's range, coordinates under ~1e-19) or past FLT_MAX (beyond ~1e19):
    // the double test answers instead of leaking a shared edge or losing the triangle.
    if (u == 0.0f || v == 0.0f || w == 0.0f || !std::isfinite(u) || !std::isfinite(v) ||
        !std::isfinite(w)) {
        if (!intersect_triangle_double(r, p0, p1, p2, tmax, hit)) return false;
        // Facing still from the float determinant where float has one (float_det_front).
        const float det = u + v + w;
        if (det != 0.0f && std::isfinite(det)) hit->front = float_det_front(det);
        return true;
    }
    if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f)) return false;
    const float det = u + v + w;
    if (det == 0.0f || !std::isfinite(det)) return false;
    const float az = r.fsz * a[r.kz], bz = r.fsz * b[r.kz], cz = r.fsz * c[r.kz];
    const float t_scaled = u * az + v * bz + w * cz;
    const float rcp_det = 1.0f / det;
    const float t = t_scaled * rcp_det;
    if (!(double(t) >= r.tmin && double(t) <= tmax)) return false;
    hit->t = t;
    hit->u = v * rcp_det;
    hit->v = w * rcp_det;
    const double da[3] = {a[0], a[1], a[2]}, db[3] = {b[0], b[1], b[2]}, dc[3] = {c[0], c[1], c[2]};
    hit->uv_error =
        barycentric_float_error(da, db, dc, largest_magnitude(ax, ay, bx, by, cx, cy), det);
    hit->front = float_det_front(det);
    return true;
}

inline bool intersect_triangle(const PreparedRay& r, const float* p0, const float* p1,
                               const float* p2, double tmax, TriangleHit* hit) {
    return r.mode == TraversalMode::kFloat32 ? intersect_triangle_float32(r, p0, p1, p2, tmax, hit)
                                             : intersect_triangle_double(r, p0, p1, p2, tmax, hit);
}

}  // namespace clastrace::engine::geometry
