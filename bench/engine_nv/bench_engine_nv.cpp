// NV bottom-level build throughput (Mtris/s) and closest-hit ray throughput (Mrays/s), one
// thread, next to Embree 3 on the same triangles: RTC_BUILD_QUALITY_LOW (its fastest
// build) and the default MEDIUM. Best of 5 runs, engine and Embree interleaved.
#include "nv_scene.h"

#include <clastrace/testsupport/rays.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

using namespace clastrace;
using namespace clastrace::nvtest;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

double embree_build(RTCDevice device, const ts::TriangleMesh& m, RTCBuildQuality quality, RTCScene* keep) {
    RTCScene scene = rtcNewScene(device);
    rtcSetSceneBuildQuality(scene, quality);
    RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(g, quality);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, m.positions.data(), 0, 12, m.positions.size());
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m.triangles.data(), 0, 12, m.triangles.size());
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    const auto t0 = Clock::now();
    rtcCommitScene(scene);
    const double s = since(t0);
    if (keep) *keep = scene;
    else rtcReleaseScene(scene);
    return s;
}

void row(const char* name, ts::TriangleMesh mesh) {
    // Embree's shared vertex buffers are read 16 bytes at a time: keep one spare vertex of capacity.
    mesh.positions.reserve(mesh.positions.size() + 2);
    NvWorld w;
    BlasSpec spec;
    spec.geometries.push_back({mesh, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    const eng::NvObjectInfo info = w.blas_info(spec);
    eng::NvObjectBinding obj = w.make_object(info, "blas");
    eng::NvBuildCommand cmd;
    cmd.info = info;
    cmd.dst = obj;
    const auto need = eng::nv_memory_requirements(info);
    cmd.scratch_address = w.scratch(need.build_scratch);
    cmd.scratch_available = need.build_scratch;
    RTCDevice device = rtcNewDevice("threads=1");
    double engine = 1e30, low = 1e30, medium = 1e30;
    uint64_t bytes = 0;
    for (int run = 0; run < 5; ++run) {
        const auto t0 = Clock::now();
        const eng::ExecutionRecord r = eng::execute_nv_build(cmd, w.memory);
        engine = std::min(engine, since(t0));
        bytes = r.ops[0].dst_size;
        low = std::min(low, embree_build(device, mesh, RTC_BUILD_QUALITY_LOW, nullptr));
        medium = std::min(medium, embree_build(device, mesh, RTC_BUILD_QUALITY_MEDIUM, nullptr));
    }
    const double mtris = mesh.triangles.size() / 1e6;
    // Rays: closest hit through the engine object and through Embree's MEDIUM scene.
    RTCScene scene = nullptr;
    embree_build(device, mesh, RTC_BUILD_QUALITY_MEDIUM, &scene);
    auto nv = eng::NvScene::open_bottom(w.memory, obj.address, nullptr);
    const auto rays = ts::random_rays(ts::bounds_of(mesh), 200000, 3);
    size_t hits_engine = 0, hits_embree = 0;
    auto t0 = Clock::now();
    for (const auto& t : rays)
        hits_engine += nv->closest(eng::Ray{{t.origin[0], t.origin[1], t.origin[2]}, 0, {t.direction[0], t.direction[1], t.direction[2]}, t.tmax}, 0, 0xFF).hit;
    const double engine_rays = since(t0);
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    t0 = Clock::now();
    for (const auto& t : rays) {
        RTCRayHit rh{};
        rh.ray = RTCRay{t.origin[0], t.origin[1], t.origin[2], 0, t.direction[0], t.direction[1], t.direction[2], 0, t.tmax, ~0u, 0, 0};
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &ctx, &rh);
        hits_embree += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    }
    const double embree_rays = since(t0);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    std::printf("%-14s %9zu %7.1f %10.2f %10.2f %10.2f %9.2fx %10.2f %10.2f %8.2fx %7zu/%zu\n", name, mesh.triangles.size(),
                double(bytes) / mesh.triangles.size(), mtris / engine, mtris / low, mtris / medium, low > 0 ? engine / low : 0.0,
                rays.size() / 1e6 / engine_rays, rays.size() / 1e6 / embree_rays, engine_rays / embree_rays, hits_engine,
                hits_embree);
}

}  // namespace

int main() {
    std::printf("NV bottom-level build and closest-hit rays, 1 thread, best of 5 (build) / 200k random rays\n");
    std::printf("%-14s %9s %7s %10s %10s %10s %10s %10s %10s %9s %15s\n", "mesh", "tris", "B/tri", "engine", "embree LOW",
                "embree MED", "LOW/eng", "eng Mray/s", "emb Mray/s", "emb/eng", "hits eng/emb");
    std::printf("%-14s %9s %7s %10s %10s %10s %10s\n", "", "", "", "Mtris/s", "Mtris/s", "Mtris/s", "time");
    row("icosphere-6", ts::make_icosphere(6, 1.0f));
    row("terrain-300", ts::make_terrain(300, 300, 1));
    row("soup-200k", ts::make_random_soup(200000, 5, 1.0f, 0.05f));
    row("torus-400x200", ts::make_torus(400, 200, 1.0f, 0.3f));
    return 0;
}
