// SPDX-License-Identifier: Apache-2.0
// One ray as Embree's rtcIntersect1/rtcOccluded1 take it: no hit yet, every mask bit set.
// For any ray type with origin[3], direction[3], tmin and tmax (the engine's Ray, TestRay).
#pragma once

#include <embree3/rtcore.h>

#include <cstring>

namespace clastrace::testsupport {

template <class Ray>
RTCRayHit embree_ray_hit(const Ray& r) {
    RTCRayHit rh;
    std::memset(&rh, 0, sizeof rh);
    rh.ray.org_x = r.origin[0];
    rh.ray.org_y = r.origin[1];
    rh.ray.org_z = r.origin[2];
    rh.ray.dir_x = r.direction[0];
    rh.ray.dir_y = r.direction[1];
    rh.ray.dir_z = r.direction[2];
    rh.ray.tnear = r.tmin;
    rh.ray.tfar = r.tmax;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    return rh;
}

}  // namespace clastrace::testsupport
