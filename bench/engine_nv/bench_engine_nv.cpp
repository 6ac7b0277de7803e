// SPDX-License-Identifier: Apache-2.0
// NV bottom-level build throughput (Mtris/s) and closest-hit ray throughput (Mrays/s), one
// thread, next to Embree 3 on the same triangles. The engine's two builders face the Embree
// builder of the same kind: the default SAH tree against RTC_BUILD_QUALITY_MEDIUM (binned
// SAH), the PREFER_FAST_BUILD Morton tree against RTC_BUILD_QUALITY_LOW (its fastest). Build
// times are best of 5, engine and Embree interleaved; the rays are one pass of 200k.
// A second table times closest-hit traversal alone (the SAH tree against Embree MEDIUM), best
// of 3 passes, wall and thread CPU time; `--quick` prints only that table, 20k rays, 1 pass;
// `--traversal RAYS PASSES` only that table at the size given; `--build-only [RUNS]` only the
// build columns (no rays: a quick build comparison), best of RUNS builds (default 5; 1 for a
// profile under callgrind, where every build counts), with the same ratios in process CPU
// time at the end of each row (SAH/MED, Morton/LOW: steadier than wall on a loaded machine)
// and the page faults of the last SAH and Morton build (0 in steady state).
#include "nv_scene.h"
#include "nv_wide_tree.h"

#include <clastrace/engine/nv_format.h>
#include <clastrace/testsupport/rays.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>

#include <sys/resource.h>

using namespace clastrace;
using namespace clastrace::nvtest;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

double thread_cpu_s() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// Page faults the process took so far (minor and major).
long page_faults() {
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_minflt + ru.ru_majflt;
}

// CPU seconds of every thread of the process: on a loaded machine steadier than wall time.
double process_cpu_s() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// Wall seconds of the commit; `cpu_s`, where given, the best of it and the commit's CPU seconds.
double embree_build(RTCDevice device, const ts::TriangleMesh& m, RTCBuildQuality quality,
                    RTCScene* keep, double* cpu_s = nullptr) {
    RTCScene scene = rtcNewScene(device);
    rtcSetSceneBuildQuality(scene, quality);
    RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(g, quality);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, m.positions.data(),
                               0, 12, m.positions.size());
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m.triangles.data(), 0,
                               12, m.triangles.size());
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    const auto t0 = Clock::now();
    const double c0 = process_cpu_s();
    rtcCommitScene(scene);
    const double s = since(t0);
    if (cpu_s) *cpu_s = std::min(*cpu_s, process_cpu_s() - c0);
    if (keep)
        *keep = scene;
    else
        rtcReleaseScene(scene);
    return s;
}

// One engine build mode on `mesh`: its best build time and its closest-hit pass.
struct EngineRun {
    double build_s = 1e30, build_cpu_s = 1e30, rays_s = 0, sah = 0;
    long faults = 0;  // page faults of the last build (steady state: fresh pages fault)
    uint64_t bytes = 0;
    size_t hits = 0;
};

struct EngineMode {
    NvWorld* world;
    eng::NvBuildCommand cmd;
    EngineMode(NvWorld& w, const ts::TriangleMesh& mesh, uint32_t flags) : world(&w) {
        BlasSpec spec;
        spec.geometries.push_back({mesh, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
        cmd.info = w.blas_info(spec, flags);
        cmd.dst = w.make_object(cmd.info, "blas");
        const auto need = eng::nv_memory_requirements(cmd.info);
        cmd.scratch_address = w.scratch(need.build_scratch);
        cmd.scratch_available = need.build_scratch;
    }
    void build(EngineRun& run) {
        const auto t0 = Clock::now();
        const double c0 = process_cpu_s();
        const long f0 = page_faults();
        const eng::ExecutionRecord r = eng::execute_nv_build(cmd, world->memory);
        run.faults = page_faults() - f0;
        run.build_s = std::min(run.build_s, since(t0));
        run.build_cpu_s = std::min(run.build_cpu_s, process_cpu_s() - c0);
        run.bytes = r.ops[0].dst_size;
    }
    void trace(EngineRun& run, const std::vector<ts::TestRay>& rays) {
        auto nv = eng::NvScene::open_bottom(world->memory, cmd.dst.address, nullptr);
        const auto t0 = Clock::now();
        for (const auto& t : rays)
            run.hits += nv->closest(eng::Ray{{t.origin[0], t.origin[1], t.origin[2]},
                                             0,
                                             {t.direction[0], t.direction[1], t.direction[2]},
                                             t.tmax},
                                    0, 0xFF)
                            .hit;
        run.rays_s = since(t0);
        run.sah = sah_cost(cmd.dst);
    }
    // The tree's SAH cost relative to its root: per node its box's half area over the root's,
    // times 1 (inner) or its item count (leaf), summed: lower traces faster.
    double sah_cost(const eng::NvObjectBinding& dst) const {
        const auto bytes = world->memory.read_bytes(dst.address, dst.size, {"bench", -1});
        const auto view = eng::open_nv_object(bytes, nullptr);
        if (!view || view->header.node_count == 0) return 0;
        auto area = [&](uint32_t i) {
            const eng::NvNode n = view->node(i);
            const double dx = double(n.bounds_max[0]) - n.bounds_min[0],
                         dy = double(n.bounds_max[1]) - n.bounds_min[1],
                         dz = double(n.bounds_max[2]) - n.bounds_min[2];
            return dx * dy + dy * dz + dz * dx;
        };
        double cost = 0;
        for (uint32_t i = 0; i < view->header.node_count; ++i)
            cost += area(i) * std::max(1u, view->node(i).count);
        return cost / area(0);
    }
};

// One mesh's build table row; `with_rays` false (--build-only) leaves the ray columns out.
// Embree's closest hit for the engine's ray: whether it hit anything.
bool embree_hits_ray(RTCScene scene, RTCIntersectContext& ctx, const ts::TestRay& t) {
    RTCRayHit rh{};
    rh.ray = RTCRay{
        t.origin[0], t.origin[1], t.origin[2], 0, t.direction[0], t.direction[1], t.direction[2], 0,
        t.tmax,      ~0u,         0,           0};
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &ctx, &rh);
    return rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
}

void row(const char* name, ts::TriangleMesh mesh, bool with_rays, int runs) {
    // Embree's shared vertex buffers are read 16 bytes at a time: keep one spare vertex of capacity.
    mesh.positions.reserve(mesh.positions.size() + 2);
    NvWorld w;
    EngineMode sah(w, mesh, 0),
        morton(w, mesh, VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV);
    RTCDevice device = rtcNewDevice("threads=1");
    EngineRun sah_run, morton_run;
    double low = 1e30, medium = 1e30, low_cpu = 1e30, medium_cpu = 1e30;
    for (int run = 0; run < runs; ++run) {
        sah.build(sah_run);
        morton.build(morton_run);
        low = std::min(low, embree_build(device, mesh, RTC_BUILD_QUALITY_LOW, nullptr, &low_cpu));
        medium = std::min(medium, embree_build(device, mesh, RTC_BUILD_QUALITY_MEDIUM, nullptr,
                                               &medium_cpu));
    }
    const double mtris = mesh.triangles.size() / 1e6;
    if (!with_rays) {
        rtcReleaseDevice(device);
        std::printf(
            "%-14s %7zu %6.1f | %7.2f %7.2f %7s %6.2fx | %7.2f %7.2f %7s %6.2fx | CPU %5.2fx "
            "%5.2fx | faults %ld %ld\n",
            name, mesh.triangles.size(), double(sah_run.bytes) / mesh.triangles.size(),
            mtris / sah_run.build_s, mtris / medium, "-", sah_run.build_s / medium,
            mtris / morton_run.build_s, mtris / low, "-", morton_run.build_s / low,
            sah_run.build_cpu_s / medium_cpu, morton_run.build_cpu_s / low_cpu, sah_run.faults,
            morton_run.faults);
        return;
    }
    // Rays: closest hit through both engine objects and through Embree's MEDIUM scene.
    RTCScene scene = nullptr;
    embree_build(device, mesh, RTC_BUILD_QUALITY_MEDIUM, &scene);
    const auto rays = ts::random_rays(ts::bounds_of(mesh), 200000, 3);
    sah.trace(sah_run, rays);
    morton.trace(morton_run, rays);
    size_t hits_embree = 0;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    const auto t0 = Clock::now();
    for (const auto& t : rays) {
        hits_embree += embree_hits_ray(scene, ctx, t);
    }
    const double embree_rays = since(t0);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    const double n = double(rays.size()) / 1e6;
    std::printf(
        "%-14s %7zu %6.1f | %7.2f %7.2f %7.2f %6.2fx | %7.2f %7.2f %7.2f %6.2fx | %7.2f %7.2f "
        "%7.2f | %6.2f %6.2f | %zu/%zu/%zu\n",
        name, mesh.triangles.size(), double(sah_run.bytes) / mesh.triangles.size(),
        mtris / sah_run.build_s, mtris / medium, n / sah_run.rays_s, sah_run.build_s / medium,
        mtris / morton_run.build_s, mtris / low, n / morton_run.rays_s, morton_run.build_s / low,
        n / embree_rays, sah_run.rays_s / embree_rays, morton_run.rays_s / embree_rays, sah_run.sah,
        morton_run.sah, sah_run.hits, morton_run.hits, hits_embree);
}

// Wall and CPU seconds of the best of `passes` runs of `trace` (the best wall's CPU).
template <class Trace>
std::pair<double, double> best_of(int passes, Trace&& trace) {
    double wall = 1e30, cpu = 1e30;
    for (int p = 0; p < passes; ++p) {
        const auto t0 = Clock::now();
        const double c0 = thread_cpu_s();
        trace();
        const double w = since(t0), c = thread_cpu_s() - c0;
        if (w < wall) {
            wall = w;
            cpu = c;
        }
    }
    return {wall, cpu};
}

// One closest-hit pass of the engine over `rays` in `mode`: the hits. Out of line, one call a
// mode, so that a profile (callgrind's inclusive cost of each) tells the modes apart.
[[gnu::noinline]] size_t engine_pass(const eng::NvScene& nv, const std::vector<ts::TestRay>& rays,
                                     eng::TraversalMode mode) {
    size_t hits = 0;
    for (const auto& t : rays)
        hits += nv.closest(eng::Ray{{t.origin[0], t.origin[1], t.origin[2]},
                                    0,
                                    {t.direction[0], t.direction[1], t.direction[2]},
                                    t.tmax},
                           0, 0xFF, mode)
                    .hit;
    return hits;
}
[[gnu::noinline]] size_t engine_pass_double(const eng::NvScene& nv,
                                            const std::vector<ts::TestRay>& rays) {
    return engine_pass(nv, rays, eng::TraversalMode::kDouble);
}
[[gnu::noinline]] size_t engine_pass_float32(const eng::NvScene& nv,
                                             const std::vector<ts::TestRay>& rays) {
    return engine_pass(nv, rays, eng::TraversalMode::kFloat32);
}

// Closest-hit traversal alone: the engine's SAH tree (NvScene, its traversal layout built at
// open) in each mode and Embree's MEDIUM scene on the same rays, one thread, the three passes
// interleaved. One row a mode, Embree's columns the same in both.
void traversal_row(const char* name, ts::TriangleMesh mesh, size_t ray_count, int passes) {
    mesh.positions.reserve(mesh.positions.size() + 2);  // Embree reads 16 bytes per vertex
    NvWorld w;
    EngineMode sah(w, mesh, 0);
    EngineRun run;
    sah.build(run);
    auto nv = eng::NvScene::open_bottom(w.memory, sah.cmd.dst.address, nullptr);
    RTCDevice device = rtcNewDevice("threads=1");
    RTCScene scene = nullptr;
    embree_build(device, mesh, RTC_BUILD_QUALITY_MEDIUM, &scene);
    const auto rays = ts::random_rays(ts::bounds_of(mesh), ray_count, 3);
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    size_t double_hits = 0, float32_hits = 0, embree_hits = 0;
    const auto double_pass = [&] { double_hits = engine_pass_double(*nv, rays); };
    const auto float32_pass = [&] { float32_hits = engine_pass_float32(*nv, rays); };
    const auto embree_pass = [&] {
        embree_hits = 0;
        for (const auto& t : rays) embree_hits += embree_hits_ray(scene, ctx, t);
    };
    std::pair<double, double> engine_double{1e30, 1e30}, engine_float32{1e30, 1e30},
        embree{1e30, 1e30};
    const auto keep_best = [](std::pair<double, double>* best, std::pair<double, double> p) {
        if (p.first < best->first) *best = p;
    };
    for (int p = 0; p < passes; ++p) {
        keep_best(&engine_double, best_of(1, double_pass));
        keep_best(&engine_float32, best_of(1, float32_pass));
        keep_best(&embree, best_of(1, embree_pass));
    }
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    const double n = double(rays.size()) / 1e6;
    uint64_t wide_nodes = 0;
    const double layout_bytes = double(nv->traversal_bytes(&wide_nodes));
    const auto print = [&](const char* mode, std::pair<double, double> engine, size_t hits) {
        std::printf(
            "%-14s %-7s %7zu %6.1f %6.2f | %7.2f %7.2f | %7.2f %7.2f | %6.2fx %6.2fx | %zu/%zu\n",
            name, mode, rays.size(), layout_bytes / mesh.triangles.size(),
            double(wide_nodes) / mesh.triangles.size(), n / engine.first, n / engine.second,
            n / embree.first, n / embree.second, embree.first / engine.first,
            embree.second / engine.second, hits, embree_hits);
    };
    print("double", engine_double, double_hits);
    print("float32", engine_float32, float32_hits);
}

void traversal_table(size_t ray_count, int passes) {
    std::printf(
        "\nClosest-hit traversal, 1 thread, %zu random rays, best of %d interleaved passes: engine "
        "(SAH tree) in each traversal mode\n(double: the default; float32: a float32 hardware "
        "pipeline's arithmetic) next to Embree MEDIUM.\nx columns: engine Mrays/s / Embree Mrays/s "
        "(1.00x: Embree's speed; the goal is >= 0.7x). B/tri kept: what the opened scene keeps "
        "to trace\n(records, stored nodes, wide nodes, leaf triangle groups); nodes/tri: wide "
        "nodes per triangle. SIMD path: %s\n(CLASTRACE_ENGINE_SIMD=sse forces the SSE 4-wide "
        "one).\n",
        ray_count, passes,
        eng::detail::active_simd_path() == eng::detail::SimdPath::kAvx2 ? "AVX2, 8-wide nodes"
                                                                        : "SSE, 4-wide nodes");
    std::printf("%-14s %-7s %7s %6s %6s | %7s %7s | %7s %7s | %7s %7s | %s\n", "mesh", "mode",
                "rays", "B/tri", "nodes", "engine", "engine", "Embree", "Embree", "ratio", "ratio",
                "hits engine/Embree");
    std::printf("%-14s %-7s %7s %6s %6s | %7s %7s | %7s %7s | %7s %7s |\n", "", "", "", "kept",
                "/tri", "wall", "CPU", "wall", "CPU", "wall", "CPU");
    traversal_row("icosphere-6", ts::make_icosphere(6, 1.0f), ray_count, passes);
    traversal_row("terrain-300", ts::make_terrain(300, 300, 1), ray_count, passes);
    traversal_row("soup-200k", ts::make_random_soup(200000, 5, 1.0f, 0.05f), ray_count, passes);
    traversal_row("torus-400x200", ts::make_torus(400, 200, 1.0f, 0.3f), ray_count, passes);
}

}  // namespace

int main(int argc, char** argv) {
    // The engine's builders use TBB for large ranges: hold them to one thread like Embree.
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    if (argc > 1 && std::strcmp(argv[1], "--quick") == 0) {
        traversal_table(20000, 1);
        return 0;
    }
    // The traversal table alone at a chosen size (profiling, interleaved before/after runs).
    if (argc == 4 && std::strcmp(argv[1], "--traversal") == 0) {
        const long rays = std::atol(argv[2]), passes = std::atol(argv[3]);
        if (rays > 0 && passes > 0) {
            traversal_table(size_t(rays), int(passes));
            return 0;
        }
    }
    const bool build_only = argc > 1 && std::strcmp(argv[1], "--build-only") == 0;
    const int runs = build_only && argc == 3 ? std::atoi(argv[2]) : 5;
    if (argc > 3 || (argc > 1 && !build_only) || (!build_only && argc > 2) || runs < 1) {
        std::fprintf(stderr,
                     "usage: %s [--quick | --traversal RAYS PASSES | --build-only [RUNS]]\n",
                     argv[0]);
        return 2;
    }
    std::printf(
        "NV bottom-level build and closest-hit rays, 1 thread, best of %d (build) / 200k random "
        "rays\n"
        "SAH: default flags, next to Embree MEDIUM (binned SAH); Morton: PREFER_FAST_BUILD, next "
        "to Embree LOW\n"
        "(its fastest build). x columns: engine time / Embree time (below 1: engine faster).\n"
        "cost: the tree's SAH cost relative to its root box (node area x items or 1; lower traces "
        "faster).\n",
        runs);
    std::printf("%-14s %7s %6s | %7s %7s %7s %7s | %7s %7s %7s %7s | %7s %7s %7s | %6s %6s | %s\n",
                "mesh", "tris", "B/tri", "SAH", "emb MED", "SAH", "SAH/MED", "Morton", "emb LOW",
                "Morton", "Mor/LOW", "emb", "SAH/emb", "Mor/emb", "SAH", "Morton",
                "hits SAH/Morton/Embree");
    std::printf("%-14s %7s %6s | %7s %7s %7s %7s | %7s %7s %7s %7s | %7s %7s %7s | %6s %6s |\n", "",
                "", "", "Mtris/s", "Mtris/s", "Mray/s", "build", "Mtris/s", "Mtris/s", "Mray/s",
                "build", "Mray/s", "rays", "rays", "cost", "cost");
    row("icosphere-6", ts::make_icosphere(6, 1.0f), !build_only, runs);
    row("terrain-300", ts::make_terrain(300, 300, 1), !build_only, runs);
    row("soup-200k", ts::make_random_soup(200000, 5, 1.0f, 0.05f), !build_only, runs);
    row("torus-400x200", ts::make_torus(400, 200, 1.0f, 0.3f), !build_only, runs);
    if (!build_only) traversal_table(200000, 3);
    return 0;
}
