// SPDX-License-Identifier: Apache-2.0
#include "clastrace/testsupport/cluster_scene.h"
#include "clastrace/testsupport/embree_ray.h"

#include "clastrace/engine/traversal.h"

#include <bit>
#include <cmath>
#include <cstring>

namespace clastrace::testsupport {
namespace {

void cluster_bounds(const RTCBoundsFunctionArguments* args) {
    const auto* scene = static_cast<const ClusterScene*>(args->geometryUserPtr);
    const Bounds& b = scene->bounds[args->primID];
    // Widened by a relative epsilon: Embree's float boxes must never cut off a triangle hit.
    auto lo = [](float v) { return v - (std::fabs(v) * 1e-6f + 1e-30f); };
    auto hi = [](float v) { return v + (std::fabs(v) * 1e-6f + 1e-30f); };
    args->bounds_o->lower_x = lo(b.lo[0]);
    args->bounds_o->lower_y = lo(b.lo[1]);
    args->bounds_o->lower_z = lo(b.lo[2]);
    args->bounds_o->upper_x = hi(b.hi[0]);
    args->bounds_o->upper_y = hi(b.hi[1]);
    args->bounds_o->upper_z = hi(b.hi[2]);
}

void cluster_intersect(const RTCIntersectFunctionNArguments* args) {
    if (!args->valid[0]) return;
    const auto* scene = static_cast<const ClusterScene*>(args->geometryUserPtr);
    auto* rh = reinterpret_cast<RTCRayHit*>(args->rayhit);  // N == 1 under rtcIntersect1
    engine::Ray r{{rh->ray.org_x, rh->ray.org_y, rh->ray.org_z},
                  rh->ray.tnear,
                  {rh->ray.dir_x, rh->ray.dir_y, rh->ray.dir_z},
                  rh->ray.tfar};
    const engine::Hit h = engine::trace_closest(scene->objects[args->primID], r, 0);
    if (!h.hit || h.t >= rh->ray.tfar) return;
    rh->ray.tfar = h.t;
    rh->hit.u = h.u;
    rh->hit.v = h.v;
    rh->hit.primID = args->primID;
    rh->hit.geomID = args->geomID;
    rh->hit.Ng_x = std::bit_cast<float>(h.triangle_index);  // carried back to trace(); not a normal
    rh->hit.instID[0] = args->context->instID[0];
}

}  // namespace

ClusterSceneTracer::ClusterSceneTracer(const ClusterScene& scene, RTCDevice device)
    : scene_(scene) {
    rtc_ = rtcNewScene(device);
    RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(g, unsigned(scene.objects.size()));
    rtcSetGeometryUserData(g, const_cast<ClusterScene*>(&scene));
    rtcSetGeometryBoundsFunction(g, cluster_bounds, nullptr);
    rtcSetGeometryIntersectFunction(g, cluster_intersect);
    rtcCommitGeometry(g);
    rtcAttachGeometry(rtc_, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(rtc_);
}

ClusterSceneTracer::~ClusterSceneTracer() { rtcReleaseScene(rtc_); }

SceneHit ClusterSceneTracer::trace(const TestRay& ray) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh = embree_ray_hit(ray);
    rtcIntersect1(rtc_, &ctx, &rh);
    SceneHit out;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return out;
    out.hit = true;
    out.t = rh.ray.tfar;
    out.u = rh.hit.u;
    out.v = rh.hit.v;
    out.cluster = rh.hit.primID;
    out.triangle = std::bit_cast<uint32_t>(rh.hit.Ng_x);
    return out;
}

}  // namespace clastrace::testsupport
