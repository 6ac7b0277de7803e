// SPDX-License-Identifier: Apache-2.0
#include "clastrace/testsupport/embree_reference.h"

#include "clastrace/testsupport/embree_ray.h"

#include <cmath>
#include <cstring>
#include <stdexcept>

namespace clastrace::testsupport {
namespace {

struct CollectContext {
    RTCIntersectContext base;  // first member: Embree hands the filter this address
    std::vector<ReferenceHit>* out;
    float t_lo;
};

void collect_filter(const RTCFilterFunctionNArguments* args) {
    auto* ctx = reinterpret_cast<CollectContext*>(args->context);
    // N is 1 for rtcIntersect1.
    RTCRay* ray = reinterpret_cast<RTCRay*>(args->ray);
    RTCHit* hit = reinterpret_cast<RTCHit*>(args->hit);
    if (ray->tfar >= ctx->t_lo) {
        ReferenceHit h;
        h.hit = true;
        h.t = ray->tfar;
        h.u = hit->u;
        h.v = hit->v;
        h.cluster = hit->geomID;
        h.triangle = hit->primID;
        ctx->out->push_back(h);
    }
    args->valid[0] = 0;  // reject, so traversal goes on and reports every candidate
}

}  // namespace

RTCDevice make_embree_device(const std::string& config) {
    RTCDevice d = rtcNewDevice(config.empty() ? nullptr : config.c_str());
    if (!d)
        throw std::runtime_error("rtcNewDevice failed: " +
                                 std::to_string(int(rtcGetDeviceError(nullptr))));
    return d;
}

RTCDevice embree_device() {
    static RTCDevice device = make_embree_device("");
    return device;
}

EmbreeReference::EmbreeReference(bool robust, RTCDevice device, RTCBuildQuality quality)
    : quality_(quality) {
    scene_ = rtcNewScene(device);
    int flags = RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION;
    if (robust) flags |= RTC_SCENE_FLAG_ROBUST;
    rtcSetSceneFlags(scene_, RTCSceneFlags(flags));
    rtcSetSceneBuildQuality(scene_, quality);
}

EmbreeReference::~EmbreeReference() { rtcReleaseScene(scene_); }

uint32_t EmbreeReference::add_cluster(std::span<const Float3> positions,
                                      std::span<const Triangle> triangles) {
    RTCGeometry geom = rtcNewGeometry(rtcGetSceneDevice(scene_), RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geom, quality_);
    // Embree may read 16 bytes at the last vertex: allocate its own padded buffers.
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                          RTC_FORMAT_FLOAT3, sizeof(Float3),
                                                          positions.size()));
    std::memcpy(v, positions.data(), positions.size_bytes());
    auto* idx = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0,
                                                               RTC_FORMAT_UINT3, sizeof(Triangle),
                                                               triangles.size()));
    std::memcpy(idx, triangles.data(), triangles.size_bytes());
    rtcCommitGeometry(geom);
    const uint32_t id = rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
    if (id != count_) throw std::logic_error("Embree geometry ids are not sequential");
    ++count_;
    return id;
}

void EmbreeReference::commit() { rtcCommitScene(scene_); }

ReferenceHit EmbreeReference::intersect(const TestRay& ray) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh = embree_ray_hit(ray);
    rtcIntersect1(scene_, &ctx, &rh);
    ReferenceHit h;
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return h;
    h.hit = true;
    h.t = rh.ray.tfar;
    h.u = rh.hit.u;
    h.v = rh.hit.v;
    h.cluster = rh.hit.geomID;
    h.triangle = rh.hit.primID;
    return h;
}

bool EmbreeReference::occluded(const TestRay& ray) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh = embree_ray_hit(ray);
    rtcOccluded1(scene_, &ctx, &rh.ray);
    return rh.ray.tfar < 0.0f;  // Embree marks an occluded ray with tfar = -inf
}

std::vector<ReferenceHit> EmbreeReference::hits_near(const TestRay& ray, float t, float rel) const {
    std::vector<ReferenceHit> out;
    CollectContext ctx;
    rtcInitIntersectContext(&ctx.base);
    ctx.base.filter = collect_filter;
    ctx.out = &out;
    const float slack = std::fabs(t) * rel + 1e-30f;
    ctx.t_lo = t - slack;
    RTCRayHit rh = embree_ray_hit(ray);
    rh.ray.tfar = std::fmin(ray.tmax, t + slack);
    rtcIntersect1(scene_, &ctx.base, &rh);
    return out;
}

}  // namespace clastrace::testsupport
