// SPDX-License-Identifier: Apache-2.0
// bench_engine_clusters: per scene, the positionTruncateBitCount trade (bytes per triangle
// against position error and hit-t deviation) and the engine's cluster build throughput on
// 1 and 2 threads beside Embree 3's RTC_BUILD_QUALITY_LOW build of the same triangles.
//
// usage: bench_engine_clusters [--quick] [--throughput-only] [--engine-only] [--repeat N]
//   --quick: ~100k-triangle scenes instead of ~10^6 (a smoke run).
//   --throughput-only: skip the truncation tables.
//   --engine-only: only the engine's 1-thread build, repeated (a clean profile under perf).
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/testsupport/cluster_scene.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <time.h>

namespace ts = clastrace::testsupport;
namespace eng = clastrace::engine;

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Process CPU seconds: on a shared, loaded machine wall time measures the neighbours too;
// CPU time measures the work (it also counts worker threads spinning, so it is pessimistic
// for multi-threaded runs).
double cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

struct Timing {
    double wall = 1e30, cpu = 1e30;
    void keep_best(const Timing& t) {
        wall = std::min(wall, t.wall);
        cpu = std::min(cpu, t.cpu);
    }
};

struct Stopwatch {
    Clock::time_point wall0 = Clock::now();
    double cpu0 = cpu_seconds();
    Timing elapsed() const { return {seconds_since(wall0), cpu_seconds() - cpu0}; }
};

int g_repeat = 3;

struct Scene {
    std::string label;
    ts::TriangleMesh mesh;
    std::vector<ts::MeshCluster> clusters;
};

ts::TriangleMesh tiled(const ts::TriangleMesh& m, int n) {
    // n x n copies side by side: a real mesh at a scene's triangle count.
    ts::TriangleMesh out;
    out.name = m.name + "x" + std::to_string(n * n);
    const ts::Bounds b = ts::bounds_of(m);
    const float dx = (b.hi[0] - b.lo[0]) * 1.1f, dz = (b.hi[2] - b.lo[2]) * 1.1f;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            const uint32_t base = uint32_t(out.positions.size());
            for (const auto& p : m.positions)
                out.positions.push_back({p[0] + i * dx, p[1], p[2] + j * dz});
            for (const auto& t : m.triangles)
                out.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
        }
    return out;
}

// Engine build of every cluster on `threads` threads (TBB arena). run() times one build of all
// clusters; the first run warms the per-thread builders and the output buffers.
struct EngineBuild {
    const ts::ClusterSceneInputs& in;
    tbb::task_arena arena;
    tbb::enumerable_thread_specific<eng::ClusterBuilder> builders;
    tbb::enumerable_thread_specific<std::vector<eng::Finding>> findings;
    std::vector<std::vector<std::byte>>& objects;
    EngineBuild(const ts::ClusterSceneInputs& inputs, int threads,
                std::vector<std::vector<std::byte>>& out)
        : in(inputs), arena(threads), objects(out) {
        objects.resize(in.infos.size());
        run();
    }
    Timing run() {
        const Stopwatch sw;
        arena.execute([&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, in.infos.size(), 32),
                              [&](const tbb::blocked_range<size_t>& r) {
                                  auto& b = builders.local();
                                  auto& f = findings.local();
                                  for (size_t i = r.begin(); i != r.end(); ++i) {
                                      f.clear();
                                      if (!b.build_triangle_cluster(in.memory, in.infos[i],
                                                                    in.input, int64_t(i),
                                                                    objects[i], f))
                                          std::fprintf(stderr, "cluster %zu failed to build\n", i);
                                  }
                              });
        });
        return sw.elapsed();
    }
};

double engine_build_seconds(const ts::ClusterSceneInputs& in, int threads,
                            std::vector<std::vector<std::byte>>& objects) {
    EngineBuild b(in, threads, objects);
    double best = 1e30;
    for (int rep = 0; rep < g_repeat; ++rep) best = std::min(best, b.run().wall);
    return best;
}

// Embree: one scene, one triangle geometry over all triangles (shared buffers), LOW quality.
// `padded` = the mesh positions plus one (Embree reads 16 bytes at the last vertex).
Timing embree_scene_seconds(const ts::TriangleMesh& mesh, const std::vector<ts::Float3>& padded,
                            RTCDevice device) {
    {
        const Stopwatch sw;
        RTCScene scene = rtcNewScene(device);
        rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_LOW);
        RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_LOW);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, padded.data(),
                                   0, 12, mesh.positions.size());
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                   mesh.triangles.data(), 0, 12, mesh.triangles.size());
        rtcCommitGeometry(g);
        rtcAttachGeometry(scene, g);
        rtcReleaseGeometry(g);
        rtcCommitScene(scene);
        const Timing s = sw.elapsed();
        rtcReleaseScene(scene);
        return s;
    }
}

// Embree: one scene per cluster (the engine's unit of work), LOW quality, built one after another.
struct ClusterArrays {
    std::vector<std::vector<ts::Float3>> pos;  // each padded by one vertex
    std::vector<std::vector<ts::Triangle>> tri;
};
ClusterArrays cluster_arrays(const Scene& sc) {
    ClusterArrays a;
    a.pos.resize(sc.clusters.size());
    a.tri.resize(sc.clusters.size());
    for (size_t c = 0; c < sc.clusters.size(); ++c) {
        for (uint32_t v : sc.clusters[c].vertices) a.pos[c].push_back(sc.mesh.positions[v]);
        a.pos[c].push_back({0, 0, 0});
        for (const auto& t : sc.clusters[c].triangles) a.tri[c].push_back({t[0], t[1], t[2]});
    }
    return a;
}

Timing embree_per_cluster_seconds(const ClusterArrays& arrays, RTCDevice device) {
    const auto& pos = arrays.pos;
    const auto& tri = arrays.tri;
    std::vector<RTCScene> scenes(pos.size());
    {
        const Stopwatch sw;
        for (size_t c = 0; c < scenes.size(); ++c) {
            scenes[c] = rtcNewScene(device);
            rtcSetSceneBuildQuality(scenes[c], RTC_BUILD_QUALITY_LOW);
            RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
            rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_LOW);
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                       pos[c].data(), 0, 12, pos[c].size() - 1);
            rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, tri[c].data(),
                                       0, 12, tri[c].size());
            rtcCommitGeometry(g);
            rtcAttachGeometry(scenes[c], g);
            rtcReleaseGeometry(g);
            rtcCommitScene(scenes[c]);
        }
        const Timing s = sw.elapsed();
        for (RTCScene s2 : scenes) rtcReleaseScene(s2);
        return s;
    }
}

struct TruncationRow {
    unsigned bits;
    double bytes_per_tri, max_abs_err, max_rel_over_bound, max_t_dev, build_ms;
    size_t flips, compared;
};

void truncation_table(const Scene& sc, const std::vector<ts::TestRay>& rays) {
    std::printf("\n== %s: %zu triangles, %zu vertices, %zu clusters (meshopt 64 v / 124 t) ==\n",
                sc.label.c_str(), sc.mesh.triangles.size(), sc.mesh.positions.size(),
                sc.clusters.size());
    std::printf("truncation table (rays for t deviation: %zu; 1 thread build)\n", rays.size());
    std::printf("%5s %8s %11s %10s %13s %11s %9s %8s %9s\n", "bits", "B/tri", "max|dx|",
                "rel/bound", "dt same tri", "dt p99", "tri chg", "hit flip", "build ms");
    std::vector<ts::SceneHit> reference;
    for (unsigned bits : {0u, 4u, 8u, 12u, 16u, 20u, 24u}) {
        const ts::ClusterSceneInputs in =
            ts::write_cluster_inputs(sc.mesh, sc.clusters, {1, 0, 0, bits});
        ts::ClusterScene scene;
        const double build_s = engine_build_seconds(in, 1, scene.objects);
        // Position error from what the objects actually store.
        double bytes = 0, max_abs = 0, max_rel = 0;
        scene.bounds.resize(sc.clusters.size());
        for (size_t c = 0; c < sc.clusters.size(); ++c) {
            bytes += double(scene.objects[c].size());
            const eng::HeaderCheck hc = eng::read_object_header(scene.objects[c]);
            if (!hc.header) {
                std::fprintf(stderr, "cluster %zu: %s\n", c, hc.error.c_str());
                continue;
            }
            for (uint32_t i = 0; i < hc.header->triangle_count; ++i) {
                const eng::DecodedTriangle t =
                    eng::decode_triangle(scene.objects[c], *hc.header, i);
                const auto& local = sc.clusters[c].triangles[t.original_index];
                for (int k = 0; k < 3; ++k) {
                    const ts::Float3& x = sc.mesh.positions[sc.clusters[c].vertices[local[k]]];
                    scene.bounds[c].extend({t.v[k][0], t.v[k][1], t.v[k][2]});
                    for (int a = 0; a < 3; ++a) {
                        const double err = std::fabs(double(t.v[k][a]) - double(x[a]));
                        max_abs = std::max(max_abs, err);
                        if (x[a] != 0.0f)
                            max_rel = std::max(max_rel, err / std::fabs(double(x[a])));
                    }
                }
            }
        }
        const ts::ClusterSceneTracer tracer(scene);
        std::vector<ts::SceneHit> hits(rays.size());
        tbb::parallel_for(size_t(0), rays.size(),
                          [&](size_t i) { hits[i] = tracer.trace(rays[i]); });
        if (bits == 0) reference = hits;
        // Same triangle hit at N and at 0 bits: the geometric effect of truncation on t. Rays
        // that change triangle (they slip past a moved silhouette edge) are counted apart.
        double max_dt_same = 0;
        std::vector<double> dts;
        size_t flips = 0, changed = 0;
        for (size_t i = 0; i < rays.size(); ++i) {
            if (hits[i].hit != reference[i].hit) {
                ++flips;
                continue;
            }
            if (!hits[i].hit) continue;
            const double dt = std::fabs(double(hits[i].t) - reference[i].t) / reference[i].t;
            dts.push_back(dt);
            if (hits[i].cluster == reference[i].cluster &&
                hits[i].triangle == reference[i].triangle)
                max_dt_same = std::max(max_dt_same, dt);
            else
                ++changed;
        }
        double p99 = 0;
        if (!dts.empty()) {
            const size_t k = size_t(0.99 * double(dts.size() - 1));
            std::nth_element(dts.begin(), dts.begin() + k, dts.end());
            p99 = dts[k];
        }
        std::printf("%5u %8.2f %11.3e %10.3f %13.3e %11.3e %9zu %8zu %9.1f\n", bits,
                    bytes / sc.mesh.triangles.size(), max_abs,
                    max_rel / std::ldexp(1.0, int(bits) - 24), max_dt_same, p99, changed, flips,
                    build_s * 1e3);
    }
}

// Surface-area estimate of one CLAS's BVH, from its stored (quantized) node boxes: for a
// ray that meets the root box, the expected node-box tests (the root, then both children of
// every interior node it reaches) and triangle tests (every triangle of every leaf it
// reaches), a node being reached with probability area(node) / area(root). No early exit:
// this measures the tree, not a ray set. Returns false for a flat root (no area).
bool sah_estimate(const std::vector<std::byte>& object, double& box_tests, double& tri_tests) {
    const eng::HeaderCheck hc = eng::read_object_header(object);
    if (!hc.header || hc.header->node_count == 0) return false;
    const eng::ObjectHeader& h = *hc.header;
    float step[3];
    for (int a = 0; a < 3; ++a) step[a] = (h.bounds_max[a] - h.bounds_min[a]) / 255.0f;
    auto area = [&](const eng::BvhNode& n) {
        double e[3];
        for (int a = 0; a < 3; ++a) {
            const double lo =
                n.qmin[a] == 0 ? h.bounds_min[a] : h.bounds_min[a] + float(n.qmin[a]) * step[a];
            const double hi =
                n.qmax[a] == 255 ? h.bounds_max[a] : h.bounds_min[a] + float(n.qmax[a]) * step[a];
            e[a] = hi - lo;
        }
        return e[0] * e[1] + e[1] * e[2] + e[2] * e[0];
    };
    eng::BvhNode root;
    std::memcpy(&root, object.data() + h.nodes_offset, sizeof root);
    const double root_area = area(root);
    if (!(root_area > 0) || !std::isfinite(root_area)) return false;
    box_tests = 1;
    tri_tests = 0;
    for (uint32_t i = 0; i < h.node_count; ++i) {
        eng::BvhNode n;
        std::memcpy(&n, object.data() + h.nodes_offset + sizeof n * i, sizeof n);
        const double p = area(n) / root_area;
        if (n.link & eng::kLeafBit)
            tri_tests += p * (((n.link >> 8) & 3) + 1);
        else
            box_tests += 2 * p;
    }
    return true;
}

// BVH quality of the engine's objects: the SAH estimate averaged over clusters, and the
// closest-hit trace rate of the whole scene (Embree's BVH over the cluster boxes, the engine
// inside each cluster; 1 thread, best of the repeats).
void quality_line(const Scene& sc, const std::vector<std::vector<std::byte>>& objects) {
    double box = 0, tri = 0;
    size_t counted = 0;
    ts::ClusterScene scene;
    scene.objects = objects;
    scene.bounds.resize(objects.size());
    for (size_t c = 0; c < objects.size(); ++c) {
        double b, t;
        if (sah_estimate(objects[c], b, t)) {
            box += b;
            tri += t;
            ++counted;
        }
        const eng::HeaderCheck hc = eng::read_object_header(objects[c]);
        if (hc.header) {
            scene.bounds[c].extend(
                {hc.header->bounds_min[0], hc.header->bounds_min[1], hc.header->bounds_min[2]});
            scene.bounds[c].extend(
                {hc.header->bounds_max[0], hc.header->bounds_max[1], hc.header->bounds_max[2]});
        }
    }
    const ts::Bounds b = ts::bounds_of(sc.mesh);
    std::vector<ts::TestRay> rays = ts::camera_rays(b, 256, 256, 3);
    const auto rnd = ts::random_rays(b, 1 << 16, 4);
    rays.insert(rays.end(), rnd.begin(), rnd.end());
    const ts::ClusterSceneTracer tracer(scene);
    double best = 1e30;
    size_t hits = 0;
    for (int rep = 0; rep < g_repeat; ++rep) {
        const Stopwatch sw;
        size_t h = 0;
        for (const auto& r : rays) h += tracer.trace(r).hit;
        best = std::min(best, sw.elapsed().cpu);
        hits = h;
    }
    std::printf(
        "BVH quality, %s: SAH estimate per cluster-box hit: %.3f node-box tests + %.3f triangle "
        "tests "
        "(mean over %zu clusters); trace %.3f Mrays/s cpu (%zu rays, %zu hits, 1 thread)\n",
        sc.label.c_str(), box / double(counted), tri / double(counted), counted,
        double(rays.size()) / 1e6 / best, rays.size(), hits);
}

void throughput_table(const Scene& sc) {
    const ts::ClusterSceneInputs in = ts::write_cluster_inputs(sc.mesh, sc.clusters, {1, 0, 0, 0});
    const double mtris = double(sc.mesh.triangles.size()) / 1e6;
    std::printf(
        "build throughput, %s (Mtris/s, best of %d runs interleaved engine/Embree so both see the "
        "same load;\n"
        "  Embree RTC_BUILD_QUALITY_LOW on the same untruncated triangles: one scene of one "
        "geometry, and one\n"
        "  scene per cluster built one after another; ratio = engine / Embree; clock wall = "
        "elapsed time,\n"
        "  cpu = process CPU time, the load-independent measure of work on a shared machine)\n",
        sc.label.c_str(), g_repeat);
    std::printf("%8s %6s %10s %16s %8s %20s %8s\n", "threads", "clock", "engine", "embree 1 scene",
                "ratio", "embree per-cluster", "ratio");
    std::vector<ts::Float3> padded = sc.mesh.positions;
    padded.push_back({0, 0, 0});
    const ClusterArrays arrays = cluster_arrays(sc);
    for (int threads : {1, 2}) {
        std::vector<std::vector<std::byte>> objects;
        EngineBuild engine(in, threads, objects);
        RTCDevice device = ts::make_embree_device("threads=" + std::to_string(threads));
        embree_scene_seconds(sc.mesh, padded, device);  // warm Embree's thread pool and allocator
        Timing e, whole, per;
        for (int rep = 0; rep < g_repeat; ++rep) {
            e.keep_best(engine.run());
            whole.keep_best(embree_scene_seconds(sc.mesh, padded, device));
            if (threads == 1) per.keep_best(embree_per_cluster_seconds(arrays, device));
        }
        rtcReleaseDevice(device);
        auto row = [&](const char* clock, double te, double tw, double tp) {
            if (threads == 1)
                std::printf("%8d %6s %10.2f %16.2f %7.2fx %20.2f %7.2fx\n", threads, clock,
                            mtris / te, mtris / tw, tw / te, mtris / tp, tp / te);
            else
                std::printf("%8d %6s %10.2f %16.2f %7.2fx %20s %8s\n", threads, clock, mtris / te,
                            mtris / tw, tw / te, "-", "-");
        };
        row("wall", e.wall, whole.wall, per.wall);
        row("cpu", e.cpu, whole.cpu, per.cpu);
        if (threads == 2) quality_line(sc, objects);
    }
}

}  // namespace

int main(int argc, char** argv) {
    bool quick = false, throughput_only = false, engine_only = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--quick")
            quick = true;
        else if (a == "--throughput-only")
            throughput_only = true;
        else if (a == "--engine-only")
            engine_only = true;
        else if (a == "--repeat" && i + 1 < argc)
            g_repeat = std::max(1, std::atoi(argv[++i]));
        else {
            std::fprintf(stderr,
                         "usage: %s [--quick] [--throughput-only] [--engine-only] [--repeat N]\n",
                         argv[0]);
            return 2;
        }
    }
    std::vector<Scene> scenes;
    const int tiles = quick ? 5 : 16;
    const auto wuson_path = ts::assimp_models_dir() / "OBJ/WusonOBJ.obj";
    try {
        scenes.push_back({"WusonOBJ tiled", tiled(ts::load_obj(wuson_path), tiles), {}});
    } catch (const ts::MeshLoadError& e) {
        std::fprintf(stderr, "no real mesh (%s); using an icosphere\n", e.what());
        scenes.push_back({"icosphere", ts::make_icosphere(quick ? 5 : 8, 10.0f), {}});
    }
    scenes.push_back(
        {"random soup", ts::make_random_soup(quick ? 100000 : 1000000, 1, 100.0f, 2.0f), {}});
    for (Scene& s : scenes) {
        const auto t0 = Clock::now();
        s.clusters = ts::build_clusters(s.mesh, 64, 124);
        std::fprintf(stderr, "%s: clustered in %.2f s\n", s.label.c_str(), seconds_since(t0));
    }
    std::printf("bench_engine_clusters: TBB, Embree %s, %u hardware threads\n", RTC_VERSION_STRING,
                std::max(1u, unsigned(tbb::info::default_concurrency())));
    std::printf(
        "columns: B/tri = CLAS object bytes / triangles; max|dx| = largest stored-minus-input "
        "coordinate;\n"
        "  rel/bound = max |dx|/|x| over coordinates, in units of the bound 2^(N-24). Zeroing N "
        "low bits\n"
        "  moves a coordinate toward zero by less than 2^N ulp, i.e. < 2^(N-23)|x| at the low end "
        "of its\n"
        "  binade, so this column stays below 2 (2^(N-24) bounds round-to-nearest; truncation, "
        "which always\n"
        "  rounds toward zero, reaches up to twice it). At N >= 24 exponent bits go too (N=24: "
        "error < |x|).\n"
        "  dt same tri = max |t_N - t_0| / t_0 over rays hitting the same triangle at N and 0 "
        "bits;\n"
        "  dt p99 = 99th percentile of that over all rays hitting at both; tri chg = rays hitting "
        "another\n"
        "  triangle; hit flip = rays hitting at one setting and missing at the other; build ms = "
        "all\n"
        "  clusters, 1 thread, best of the repeats.\n");
    if (engine_only) {
        for (const Scene& s : scenes) {
            const ts::ClusterSceneInputs in =
                ts::write_cluster_inputs(s.mesh, s.clusters, {1, 0, 0, 0});
            std::vector<std::vector<std::byte>> objects;
            EngineBuild engine(in, 1, objects);
            Timing best;
            for (int rep = 0; rep < g_repeat; ++rep) best.keep_best(engine.run());
            const double mtris = double(s.mesh.triangles.size()) / 1e6;
            std::printf(
                "%s: engine build, 1 thread, best of %d: wall %.2f ms (%.2f Mtris/s), cpu %.2f ms "
                "(%.2f Mtris/s)\n",
                s.label.c_str(), g_repeat, best.wall * 1e3, mtris / best.wall, best.cpu * 1e3,
                mtris / best.cpu);
            quality_line(s, objects);
        }
        return 0;
    }
    for (const Scene& s : scenes) {
        const ts::Bounds b = ts::bounds_of(s.mesh);
        std::vector<ts::TestRay> rays = ts::camera_rays(b, 256, 256, 3);
        const auto rnd = ts::random_rays(b, quick ? 1 << 15 : 1 << 17, 4);
        rays.insert(rays.end(), rnd.begin(), rnd.end());
        if (!throughput_only) truncation_table(s, rays);
        throughput_table(s);
    }
    return 0;
}
