// SPDX-License-Identifier: Apache-2.0
// The engine's one ray/triangle test: watertight (Woop, Benthin & Wald 2013: dimension
// permutation, shear, edge functions) in double precision, so that coordinates up to
// ±FLT_MAX neither overflow nor lose the watertight property. Edge functions equal to
// zero count as inside; a triangle whose edge functions are all zero (seen edge-on,
// degenerate) or not finite is missed. Hits lie in the closed interval [tmin, tmax].
#pragma once

#include "geometry/ray.h"

#include <cmath>

namespace clastrace::engine::geometry {

struct TriangleHit {
    double t;
    double u, v;  // barycentric weights of p1 and p2
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

inline bool intersect_triangle(const PreparedRay& r, const float* p0, const float* p1,
                               const float* p2, double tmax, TriangleHit* hit) {
    double a[3], b[3], c[3];
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
    hit->front = front_facing(r.d, p0, p1, p2);
    return true;
}

}  // namespace clastrace::engine::geometry
