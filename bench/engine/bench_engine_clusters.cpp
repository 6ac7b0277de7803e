// SPDX-License-Identifier: Apache-2.0
// bench_engine_clusters: per scene, the positionTruncateBitCount trade (bytes per triangle
// against position error and hit-t deviation) and the engine's cluster build throughput at
// every thread count of a sweep (1, 2, 4, ... and the machine's count) beside Embree 3's
// RTC_BUILD_QUALITY_LOW build of the same triangles at the same count, with each builder's
// scaling efficiency, and the engine's scaling losses by cause (the phases table: when the
// last thread started, how evenly the chunks were shared, CPU per cluster against the
// 1-thread run, and the input and object bytes moved per second); the header says whether
// cpu0 shares its core with an SMT sibling.
//
// usage: bench_engine_clusters [--quick] [--tris N] [--max-threads N] [--mesh PATH]
//                              [--throughput-only] [--builds-only] [--engine-only] [--repeat N]
//                              [--scene TEXT] [--thread-cpu] [--cold] [--streaming-objects]
//                              [--single-build] [--grain N] [--counts LIST] [--sweeps N]
//                              [--both-measures]
//   --tris N: about N triangles per scene (default 10^6); --quick: 10^5 (a smoke run).
//   --max-threads N: the sweep's last count (default: the machine's hardware threads).
//   --mesh PATH: the WusonOBJ model to tile (default: Debian's assimp-testmodels copy).
//   --throughput-only: skip the truncation tables.
//   --builds-only: --throughput-only without the BVH quality and trace lines after each table
//     (both builders' instructions under callgrind in minutes, not hours).
//   --engine-only: only the engine's 1-thread build, repeated, no tracing (a clean profile
//     under perf).
//   --scene TEXT: only the scenes whose label contains TEXT ("WusonOBJ", "icosphere", "soup"),
//     e.g. to count one mesh's instructions per cluster under callgrind.
//   --thread-cpu: also time each chunk's thread CPU (the phases table's cpu column: cost per
//     cluster without preemption by other processes; a system call per chunk end).
//   --cold: before every timed build, evict its inputs and outputs from all caches (x86
//     CLFLUSH): both builders then read and write a scene in memory at every thread count.
//   --streaming-objects: the engine writes each object with non-temporal stores
//     (engine::ObjectStores::kStreaming): its lines are not read for ownership first.
//   --single-build: a timed run at N threads is one build whose threads it wakes (before
//     session 17), not one untimed build and then the mean of N builds back to back.
//   --grain N: the engine's parallel loop takes chunks of at least N clusters (default 8;
//     32 before session 17).
//   --counts LIST: the sweep's thread counts after 1, e.g. "16" or "4,16".
//   --sweeps N: each scene's throughput table N times (one clustering for all).
//   --both-measures: each sweep twice, in the measure chosen and in session 16's
//     (--single-build --grain 32), alternating which goes first: the two measures compared
//     in one process.
#include "clastrace/engine/blas.h"
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/testsupport/cluster_scene.h"
#include "scaling_probes.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <cstdlib>
#include <filesystem>
#include <new>
#include <optional>
#include <string>
#include <thread>
#include <time.h>
#include <utility>

namespace ts = clastrace::testsupport;
namespace eng = clastrace::engine;
namespace cb = clastrace::bench;

// Heap allocations made by this thread and their bytes (operator new, replaced below): the
// machine table counts those inside the engine's timed chunks. Per-thread counts, so counting
// shares no line.
thread_local uint64_t t_allocations = 0;
thread_local uint64_t t_allocated_bytes = 0;

void* operator new(std::size_t size) {
    ++t_allocations;
    t_allocated_bytes += size;
    if (void* p = std::malloc(size ? size : 1)) return p;
    throw std::bad_alloc();
}
void* operator new(std::size_t size, std::align_val_t align) {
    ++t_allocations;
    t_allocated_bytes += size;
    const std::size_t a = std::max(std::size_t(align), sizeof(void*));
    if (void* p = std::aligned_alloc(a, (std::max<std::size_t>(size, 1) + a - 1) / a * a)) return p;
    throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Process CPU seconds: on a shared, loaded machine wall time measures the neighbours too;
// CPU time measures the work (it also counts worker threads spinning, so it is pessimistic
// for multi-threaded runs).
double cpu_seconds(clockid_t clock = CLOCK_PROCESS_CPUTIME_ID) {
    timespec ts{};
    clock_gettime(clock, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

struct Timing {
    double wall = 1e30, cpu = 1e30;
    void keep_best(const Timing& t) {
        wall = std::min(wall, t.wall);
        cpu = std::min(cpu, t.cpu);
    }
};

// The mean of `builds` timed builds (each timed alone).
struct TimingSum {
    Timing sum{0, 0};
    int builds = 0;
    void add(const Timing& t) {
        sum.wall += t.wall;
        sum.cpu += t.cpu;
        ++builds;
    }
    Timing mean() const { return {sum.wall / builds, sum.cpu / builds}; }
};

struct Stopwatch {
    Clock::time_point wall0 = Clock::now();
    double cpu0 = cpu_seconds();
    Timing elapsed() const { return {seconds_since(wall0), cpu_seconds() - cpu0}; }
};

int g_repeat = 3;
// Time each chunk's thread CPU too: a system call per read (7.8 us on the loaded 2-core
// development container, against chunks of 0.1-0.2 ms), so off unless asked for (--thread-cpu).
bool g_thread_cpu = false;
// Evict each builder's inputs and outputs from the caches before its timed runs (--cold): the
// 1-thread run then no longer finds a whole scene left in the last-level cache by its previous
// run, where N threads find each cluster's lines in another core's cache.
bool g_cold = false;
// How the engine writes its objects (--streaming-objects).
eng::ObjectStores g_object_stores = eng::ObjectStores::kCached;
// How a thread count's run is timed. By default one untimed build first, then N builds back to
// back at N threads, their mean the run's time: each builder's threads then start every timed
// build awake (not woken from the sleep that settle() gives them), on cores at the clock their
// load holds, and the timed interval is about one 1-thread build at every count. Session 16's
// measure (--single-build) timed one build a run whose threads it woke: on the device VM the
// last of 16 threads started 4-11% of a 3-5 ms build late (0.3-1% with this measure). Chunks
// of 8 clusters (--grain): with 32, the busiest of 16 threads ended 2.5-5% after the mean
// (0.4-2% with 8).
struct Measure {
    bool single_build = false;
    size_t grain = 8;  // clusters per chunk of the parallel loop (the bench's, not the engine's)
};
constexpr Measure kSession16Measure{true, 32};
Measure g_measure;

// Untimed builds before a timed run's, and timed builds in it, at `threads` threads.
int warm_builds() { return g_measure.single_build ? 0 : 1; }
int timed_builds(int threads) { return g_measure.single_build ? 1 : threads; }

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

// Where one parallel engine build's wall time went: each thread's busy time (inside the loop
// body, its chunks of clusters) and how long after the run began it took its first chunk. With
// `threads` threads, wall >= latest start + busy of that thread; busy summed over threads
// against the 1-thread run's busy says whether a cluster costs more CPU on a full machine
// (shared caches, memory bandwidth, clock), busy max against the mean whether the chunks were
// shared unevenly.
struct PhaseStats {
    double busy_sum = 0, busy_max = 0, latest_start = 0;
    double busy_cpu_sum = 0;  // the threads' own CPU time in the chunks: busy less preemption
    int threads_used = 0;
    double allocations = 0;      // inside the chunks, all threads
    double allocated_bytes = 0;  // the same allocations' bytes
    double minor_faults = 0;     // the whole process during the run
    // Sums another build's stats into these (the mean over a run's builds: divide by them).
    void add(const PhaseStats& p) {
        busy_sum += p.busy_sum, busy_max += p.busy_max, latest_start += p.latest_start;
        busy_cpu_sum += p.busy_cpu_sum;
        threads_used = std::max(threads_used, p.threads_used);
        allocations += p.allocations, allocated_bytes += p.allocated_bytes;
        minor_faults += p.minor_faults;
    }
    PhaseStats per_build(int builds) const {
        PhaseStats m = *this;
        m.busy_sum /= builds, m.busy_max /= builds, m.latest_start /= builds;
        m.busy_cpu_sum /= builds;
        m.allocations /= builds, m.allocated_bytes /= builds, m.minor_faults /= builds;
        return m;
    }
};

// One thread's share of a run.
struct ThreadPhase {
    double busy = 0, first_start = -1, busy_cpu = 0;
    uint64_t allocations = 0, allocated_bytes = 0;
};

// Engine build of every cluster on `threads` threads (TBB arena). run() times builds of all
// clusters; the first run warms the per-thread builders and the output buffers.
struct EngineBuild {
    const ts::ClusterSceneInputs& in;
    tbb::task_arena arena;
    tbb::enumerable_thread_specific<eng::ClusterBuilder> builders;
    tbb::enumerable_thread_specific<std::vector<eng::Finding>> findings;
    tbb::enumerable_thread_specific<ThreadPhase> phases;
    std::vector<std::vector<std::byte>>& objects;
    PhaseStats last;  // of the latest run, the mean of its timed builds
    EngineBuild(const ts::ClusterSceneInputs& inputs, int threads,
                std::vector<std::vector<std::byte>>& out)
        : in(inputs), arena(threads), objects(out) {
        objects.resize(in.infos.size());
        run();
    }
    void build_chunk(const tbb::blocked_range<size_t>& r) {
        auto& b = builders.local();
        b.set_object_stores(g_object_stores);
        auto& f = findings.local();
        for (size_t i = r.begin(); i != r.end(); ++i) {
            f.clear();
            if (!b.build_triangle_cluster(in.memory, in.infos[i], in.input, int64_t(i), objects[i],
                                          f))
                std::fprintf(stderr, "cluster %zu failed to build\n", i);
        }
    }
    void evict() const {
        for (const auto& [base, region] : in.memory.regions())
            cb::evict_lines(std::as_const(region.bytes).data(), region.bytes.size());
        cb::evict_lines(in.infos.data(), in.infos.size() * sizeof in.infos[0]);
        for (const auto& o : objects) cb::evict_lines(o.data(), o.capacity());
    }
    // `warm` untimed builds, then `builds` timed ones (each evicted first with --cold): the
    // mean of the timed builds, their mean phases in `last`.
    Timing run(int warm = 0, int builds = 1) {
        for (int w = 0; w < warm; ++w) build_once(Clock::now());
        TimingSum sum;
        PhaseStats phases_sum;
        for (int k = 0; k < builds; ++k) {
            if (g_cold) evict();
            const double faults0 = double(cb::minor_faults());
            const Stopwatch sw;
            build_once(sw.wall0);
            sum.add(sw.elapsed());
            PhaseStats p = collect_phases();
            p.minor_faults = double(cb::minor_faults()) - faults0;
            phases_sum.add(p);
        }
        last = phases_sum.per_build(builds);
        return sum.mean();
    }
    // One parallel build of every cluster, each chunk's phase taken from `t0` (the build's start).
    void build_once(Clock::time_point t0) {
        for (ThreadPhase& p : phases) p = ThreadPhase{};
        arena.execute([&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, in.infos.size(), g_measure.grain),
                              [&](const tbb::blocked_range<size_t>& r) { timed_chunk(r, t0); });
        });
    }
    void timed_chunk(const tbb::blocked_range<size_t>& r, Clock::time_point t0) {
        const auto c0 = Clock::now();
        ThreadPhase& p = phases.local();
        if (p.first_start < 0) p.first_start = std::chrono::duration<double>(c0 - t0).count();
        const uint64_t a0 = t_allocations;
        const uint64_t bytes0 = t_allocated_bytes;
        const double cpu0 = g_thread_cpu ? cpu_seconds(CLOCK_THREAD_CPUTIME_ID) : 0;
        build_chunk(r);
        if (g_thread_cpu) p.busy_cpu += cpu_seconds(CLOCK_THREAD_CPUTIME_ID) - cpu0;
        p.allocations += t_allocations - a0;
        p.allocated_bytes += t_allocated_bytes - bytes0;
        p.busy += seconds_since(c0);
    }
    // The threads' phases of the latest build (its faults are the caller's to add).
    PhaseStats collect_phases() {
        PhaseStats s;
        for (const ThreadPhase& p : phases) {
            if (p.first_start < 0) continue;
            ++s.threads_used;
            s.allocations += double(p.allocations);
            s.allocated_bytes += double(p.allocated_bytes);
            s.busy_sum += p.busy;
            s.busy_cpu_sum += p.busy_cpu;
            s.busy_max = std::max(s.busy_max, p.busy);
            s.latest_start = std::max(s.latest_start, p.first_start);
        }
        return s;
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
    if (g_cold) {
        cb::evict_lines(padded.data(), padded.size() * sizeof padded[0]);
        cb::evict_lines(mesh.triangles.data(), mesh.triangles.size() * sizeof mesh.triangles[0]);
    }
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
    if (g_cold)
        for (size_t c = 0; c < pos.size(); ++c) {
            cb::evict_lines(pos[c].data(), pos[c].size() * sizeof pos[c][0]);
            cb::evict_lines(tri[c].data(), tri[c].size() * sizeof tri[c][0]);
        }
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

// The engine alone: a cluster BLAS over the scene's CLASes (its binned SAH build), traced
// closest hit through trace_bottom_level_bytes in both traversal modes (1 thread, best of the
// repeats): the BLAS walk and the CLAS walk, no Embree.
void cluster_blas_trace_line(const Scene& sc, const std::vector<std::vector<std::byte>>& objects,
                             const std::vector<ts::TestRay>& test_rays) {
    std::vector<eng::ClusterBox> boxes;
    for (size_t c = 0; c < objects.size(); ++c) {
        const eng::HeaderCheck hc = eng::read_object_header(objects[c]);
        if (!hc.header || hc.header->node_count == 0) continue;
        eng::ClusterBox box{};
        std::memcpy(box.bounds_min, hc.header->bounds_min, 12);
        std::memcpy(box.bounds_max, hc.header->bounds_max, 12);
        box.clas_address = c;
        box.reference_index = uint32_t(c);
        box.cluster_id = hc.header->cluster_id;
        boxes.push_back(box);
    }
    const std::vector<std::byte> blas = eng::build_bottom_level(boxes, uint32_t(objects.size()));
    if (blas.empty()) return;
    const auto clas_at = [&](uint64_t address) -> std::span<const std::byte> {
        return objects[size_t(address)];
    };
    std::vector<eng::Ray> rays;
    for (const auto& t : test_rays)
        rays.push_back(eng::Ray{{t.origin[0], t.origin[1], t.origin[2]},
                                t.tmin,
                                {t.direction[0], t.direction[1], t.direction[2]},
                                t.tmax});
    std::vector<std::optional<eng::ClasView>> views;
    for (const auto& o : objects) views.push_back(eng::open_clas(o));
    const auto view_at = [&](uint64_t address) -> const eng::ClasView* {
        return views[size_t(address)] ? &*views[size_t(address)] : nullptr;
    };
    // Checked per visit (the bytes form) and opened once (the views form).
    for (const bool opened : {false, true}) {
        for (const eng::TraversalMode mode :
             {eng::TraversalMode::kDouble, eng::TraversalMode::kFloat32}) {
            double best = 1e30;
            size_t hits = 0;
            for (int rep = 0; rep < g_repeat; ++rep) {
                const Stopwatch sw;
                size_t h = 0;
                for (const auto& r : rays)
                    h += (opened ? eng::trace_bottom_level_views(blas, view_at, r, 0, false, mode)
                                 : eng::trace_bottom_level_bytes(blas, clas_at, r, 0, false, mode))
                             .hit.hit;
                best = std::min(best, sw.elapsed().cpu);
                hits = h;
            }
            std::printf(
                "cluster BLAS trace, %s, %s, %s: %.3f Mrays/s cpu (%zu rays, %zu hits, "
                "1 thread, engine only)\n",
                sc.label.c_str(), eng::traversal_mode_name(mode),
                opened ? "CLASes opened once" : "CLAS checked per visit",
                double(rays.size()) / 1e6 / best, rays.size(), hits);
        }
    }
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
    cluster_blas_trace_line(sc, objects, rays);
}

// The thread counts of the sweep: 1, 2, 4, ... below `max_threads`, then `max_threads` itself;
// or --counts' list, after 1 (every count's efficiency is against it).
std::vector<int> g_counts;
std::vector<int> thread_sweep(int max_threads) {
    std::vector<int> counts;
    if (!g_counts.empty()) {
        counts.push_back(1);
        for (int t : g_counts)
            if (t > 1) counts.push_back(t);
        return counts;
    }
    for (int t = 1; t < max_threads; t *= 2) counts.push_back(t);
    counts.push_back(max_threads);
    return counts;
}

// One thread count's best times: the engine, Embree LOW on one scene, and (1 thread only)
// Embree LOW per cluster.
struct SweepTimes {
    int threads;
    Timing engine, whole, per_cluster;
    PhaseStats engine_phases;  // of the engine's best wall
    cb::CoreRates rates;       // the ALU loops at this count, best of the repeats
};

// The other builder's TBB workers spin for a while after its run, and process CPU time would
// count them against the next timed run: let them fall asleep first.
void settle() { std::this_thread::sleep_for(std::chrono::milliseconds(30)); }

SweepTimes time_thread_count(const Scene& sc, const ts::ClusterSceneInputs& in,
                             const std::vector<ts::Float3>& padded, const ClusterArrays& arrays,
                             int threads, std::vector<std::vector<std::byte>>& objects,
                             cb::TrafficProbe& probe) {
    EngineBuild engine(in, threads, objects);
    // Embree's thread count is its TBB scheduler's, set once per process by the first device's
    // "threads=" (later devices' are ignored): so no device sets it, and Embree commits inside
    // an arena of `threads`, as the engine builds.
    RTCDevice device = ts::make_embree_device("");
    tbb::task_arena embree_arena(threads);
    const auto embree_run = [&](auto&& build) {
        settle();
        Timing t;
        embree_arena.execute([&] { t = build(); });
        return t;
    };
    // Embree's run as the engine's (warm_builds, timed_builds).
    const auto embree_whole = [&] {
        TimingSum sum;
        for (int w = 0; w < warm_builds(); ++w) embree_scene_seconds(sc.mesh, padded, device);
        for (int k = 0; k < timed_builds(threads); ++k)
            sum.add(embree_scene_seconds(sc.mesh, padded, device));
        return sum.mean();
    };
    embree_run([&] { return embree_scene_seconds(sc.mesh, padded, device); });  // warm up
    SweepTimes t{threads, {}, {}, {}, {}, {}};
    for (int rep = 0; rep < g_repeat; ++rep) {
        settle();
        const Timing e = engine.run(warm_builds(), timed_builds(threads));
        if (e.wall < t.engine.wall) t.engine_phases = engine.last;
        t.engine.keep_best(e);
        t.whole.keep_best(embree_run(embree_whole));
        if (threads == 1)
            t.per_cluster.keep_best(
                embree_run([&] { return embree_per_cluster_seconds(arrays, device); }));
        settle();
        t.rates.keep_best(cb::core_rates(threads, probe));
    }
    rtcReleaseDevice(device);
    return t;
}

// Bytes one engine build moves through memory: every cluster's input (its info struct, the
// vertex and index bytes it names) and its object. With the wall time, the memory traffic a
// thread count asks of the machine (a lower bound: writes also read their lines first).
struct BuildTraffic {
    double input_bytes = 0, output_bytes = 0;
};
BuildTraffic build_traffic(const ts::ClusterSceneInputs& in,
                           const std::vector<std::vector<std::byte>>& objects) {
    BuildTraffic t;
    for (const auto& info : in.infos) {
        const uint32_t istep = info.indexBufferStride ? info.indexBufferStride : info.indexType;
        const uint32_t vstep = info.vertexBufferStride ? info.vertexBufferStride : 12;
        t.input_bytes += double(sizeof info) + double(info.vertexCount) * vstep +
                         3.0 * info.triangleCount * istep;
    }
    for (const auto& o : objects) t.output_bytes += double(o.size());
    return t;
}

// The engine's scaling losses by cause, per thread count (its best-wall run): threads that
// took chunks; the latest first chunk (waking the workers); busy per thread, mean and max
// (uneven chunks); wall time outside the busiest thread's chunks; "cost/cluster", all
// threads' busy time over the 1-thread run's (above 1: every cluster costs more CPU when all
// cores build, e.g. memory bandwidth, clock or two threads sharing a core), and the same of the
// threads' own CPU time (what is left when other processes preempt the threads); and the memory
// traffic of inputs and objects per second of wall time.
void phase_table(const std::vector<SweepTimes>& sweep, const BuildTraffic& traffic,
                 size_t clusters) {
    std::printf(
        "engine phases (best-wall run per count, the mean of its builds; ms): used = threads that "
        "took chunks,\n  start = latest first chunk, busy = time in the chunks per thread (mean, "
        "max), outside = wall -\n  busy max (scheduling, preemption, the join), cost/cluster = "
        "busy of all threads / 1-thread\n  busy (wall; cpu: the threads' CPU time, with "
        "--thread-cpu), GB/s = input and object bytes\n  (%.0f + %.0f B per cluster; the object's "
        "lines %s) / wall\n",
        traffic.input_bytes / double(clusters), traffic.output_bytes / double(clusters),
        g_object_stores == eng::ObjectStores::kStreaming ? "streamed, not read first"
                                                         : "also read for ownership");
    std::printf("%8s %6s %9s %8s %10s %9s %8s %13s %7s %7s\n", "threads", "used", "wall", "start",
                "busy mean", "busy max", "outside", "cost/cluster", "cpu", "GB/s");
    if (sweep.empty()) return;
    const PhaseStats& one = sweep.front().engine_phases;
    for (const SweepTimes& t : sweep) {
        const PhaseStats& p = t.engine_phases;
        char cpu[16] = "-";
        if (g_thread_cpu)
            std::snprintf(cpu, sizeof cpu, "%.2fx", p.busy_cpu_sum / one.busy_cpu_sum);
        std::printf("%8d %6d %9.3f %8.3f %10.3f %9.3f %8.3f %12.2fx %7s %7.2f\n", t.threads,
                    p.threads_used, t.engine.wall * 1e3, p.latest_start * 1e3,
                    p.threads_used ? p.busy_sum / p.threads_used * 1e3 : 0.0, p.busy_max * 1e3,
                    (t.engine.wall - p.busy_max) * 1e3, p.busy_sum / one.busy_sum, cpu,
                    (traffic.input_bytes + traffic.output_bytes) / t.engine.wall / 1e9);
    }
}

// What the machine takes from every thread when all build, measured beside the build with no
// build work: the clock (the dependent ALU chain's per-thread rate against one thread's), core
// sharing (the eight chains'), the memory system (the traffic probe's); the engine's cost per
// cluster in clock cycles (cost/cluster x clock: above 1, a cluster itself costs more cycles,
// e.g. shared caches or memory); and the run's minor page faults and heap allocations with
// their bytes.
void machine_table(const std::vector<SweepTimes>& sweep, size_t clusters) {
    std::printf(
        "machine (per-thread rate on all threads at once vs 1 thread, best of the repeats): clock "
        "= a dependent\n  multiply chain, ports = 8 independent chains, memory = the traffic probe "
        "(each cluster's input bytes\n  read and object bytes written, no work); cost@clock = "
        "cost/cluster x clock (cycles per cluster vs\n  1 thread); faults, allocs, alloc B = minor "
        "page faults (process), heap allocations and their\n  bytes (in the chunks) per 1000 "
        "clusters of the best-wall run\n");
    std::printf("%8s %6s %6s %6s %10s %7s %7s %8s\n", "threads", "clock", "ports", "memory",
                "cost@clock", "faults", "allocs", "alloc B");
    if (sweep.empty()) return;
    const double one_busy = sweep.front().engine_phases.busy_sum;
    const cb::CoreRates& one = sweep.front().rates;
    const double per_k = 1000.0 / double(clusters);
    for (const SweepTimes& t : sweep) {
        const PhaseStats& p = t.engine_phases;
        const double clock = one.chain / t.rates.chain;
        std::printf("%8d %6.2f %6.2f %6.2f %9.2fx %7.2f %7.2f %8.0f\n", t.threads, clock,
                    one.ports / t.rates.ports, one.memory / t.rates.memory,
                    p.busy_sum / one_busy * clock, double(p.minor_faults) * per_k,
                    double(p.allocations) * per_k, double(p.allocated_bytes) * per_k);
    }
}

// The throughput table's title and what its columns mean.
void throughput_header(const Scene& sc) {
    std::printf(
        "\nbuild throughput, %s, %zu triangles, %zu clusters (Mtris/s, best of %d runs "
        "interleaved engine/Embree\n"
        "  so both see the same load; a run: see the measure line below; Embree "
        "RTC_BUILD_QUALITY_LOW on\n"
        "  the same untruncated triangles: one scene of one geometry, and (1 thread) one scene "
        "per cluster\n"
        "  built one after another; ratio = engine / Embree at the same thread count; eff = "
        "scaling efficiency\n"
        "  (speedup over its own 1-thread wall / threads);\n"
        "  clock wall = elapsed time, cpu = process CPU time, the load-independent measure of "
        "work on a shared machine;\n"
        "  calib = per-thread rate of fixed loops on all threads at once vs 1 thread: under eng "
        "eff a dependent\n"
        "  multiply chain (the clock; at 1 thread the clock it implies at 4 cycles per step), "
        "under emb eff 8\n"
        "  independent chains (the clock and core sharing), then the traffic probe (memory); "
        "eng eff / clock =\n"
        "  the engine's efficiency with the clock's share taken out)\n",
        sc.label.c_str(), sc.mesh.triangles.size(), sc.clusters.size(), g_repeat);
    if (g_measure.single_build)
        std::printf(
            "  measure: one build a timed run, its threads woken by it; %zu-cluster chunks\n",
            g_measure.grain);
    else
        std::printf(
            "  measure: at N threads 1 untimed build, then the mean of N builds; %zu-cluster "
            "chunks\n",
            g_measure.grain);
}

// Engine and Embree LOW at every thread count of the sweep. Scaling efficiency = (1-thread
// wall / N-thread wall) / N, each builder against its own 1-thread run; on CPU time rows it
// is not shown (CPU time counts every thread's work, so it is flat under perfect scaling).
void throughput_table(const Scene& sc, int max_threads, bool with_quality) {
    const ts::ClusterSceneInputs in = ts::write_cluster_inputs(sc.mesh, sc.clusters, {1, 0, 0, 0});
    const double mtris = double(sc.mesh.triangles.size()) / 1e6;
    throughput_header(sc);
    std::printf("%8s %6s %10s %10s %8s %7s %7s %20s %8s\n", "threads", "clock", "engine",
                "embree LOW", "ratio", "eng eff", "emb eff", "embree per-cluster", "ratio");
    std::vector<ts::Float3> padded = sc.mesh.positions;
    padded.push_back({0, 0, 0});
    const ClusterArrays arrays = cluster_arrays(sc);
    std::vector<std::vector<std::byte>> objects;
    EngineBuild(in, 1, objects);  // the objects' sizes, for the traffic probe
    const BuildTraffic traffic = build_traffic(in, objects);
    const size_t clusters = sc.clusters.size();
    cb::TrafficProbe probe(clusters, size_t(traffic.input_bytes / double(clusters)),
                           size_t(traffic.output_bytes / double(clusters)));
    SweepTimes one{};
    std::vector<SweepTimes> sweep;
    for (int threads : thread_sweep(max_threads)) {
        const SweepTimes t = time_thread_count(sc, in, padded, arrays, threads, objects, probe);
        sweep.push_back(t);
        if (threads == 1) one = t;
        const Timing& e = t.engine;
        const Timing& w = t.whole;
        std::printf("%8d %6s %10.2f %10.2f %7.2fx %7.2f %7.2f", threads, "wall", mtris / e.wall,
                    mtris / w.wall, w.wall / e.wall, one.engine.wall / e.wall / threads,
                    one.whole.wall / w.wall / threads);
        if (threads == 1)
            std::printf(" %20.2f %7.2fx\n", mtris / t.per_cluster.wall,
                        t.per_cluster.wall / e.wall);
        else
            std::printf(" %20s %8s\n", "-", "-");
        std::printf("%8d %6s %10.2f %10.2f %7.2fx %7s %7s", threads, "cpu", mtris / e.cpu,
                    mtris / w.cpu, w.cpu / e.cpu, "-", "-");
        if (threads == 1)
            std::printf(" %20.2f %7.2fx\n", mtris / t.per_cluster.cpu, t.per_cluster.cpu / e.cpu);
        else
            std::printf(" %20s %8s\n", "-", "-");
        const double clock = one.rates.chain / t.rates.chain;
        std::printf("%8d %6s %10s %10s %8s %7.2f %7.2f  memory %.2f; ", threads, "calib", "-", "-",
                    "-", clock, one.rates.ports / t.rates.ports, one.rates.memory / t.rates.memory);
        if (threads == 1)
            std::printf("clock %.2f GHz\n", double(cb::kChainIterations) *
                                                cb::kChainCyclesPerIteration / t.rates.chain / 1e9);
        else
            std::printf("eng eff / clock %.2f\n", one.engine.wall / e.wall / threads / clock);
    }
    phase_table(sweep, traffic, clusters);
    machine_table(sweep, clusters);
    if (with_quality) quality_line(sc, objects);
}

// The bench's meshes at about `tris` triangles each: the WusonOBJ model tiled (when `wuson`
// loads), the icosphere, and a random soup; only those whose label contains `only`.
std::vector<Scene> make_scenes(size_t tris, const std::filesystem::path& wuson,
                               const std::string& only) {
    std::vector<Scene> scenes;
    try {
        const ts::TriangleMesh model = ts::load_obj(wuson);
        const int tiles =
            std::max(1, int(std::lround(std::sqrt(double(tris) / double(model.triangles.size())))));
        scenes.push_back({"WusonOBJ tiled", tiled(model, tiles), {}});
    } catch (const ts::MeshLoadError& e) {
        std::fprintf(stderr, "no WusonOBJ (%s): the icosphere is the only real mesh\n", e.what());
    }
    // 20 * 4^s triangles: the subdivision nearest to `tris` on a log scale.
    const int subdivisions =
        std::clamp(int(std::lround(std::log(double(tris) / 20.0) / std::log(4.0))), 1, 10);
    scenes.push_back({"icosphere", ts::make_icosphere(subdivisions, 10.0f), {}});
    scenes.push_back({"random soup", ts::make_random_soup(tris, 1, 100.0f, 2.0f), {}});
    std::erase_if(scenes, [&](const Scene& s) { return s.label.find(only) == std::string::npos; });
    for (Scene& s : scenes) {
        const auto t0 = Clock::now();
        s.clusters = ts::build_clusters(s.mesh, 64, 124);
        std::fprintf(stderr, "%s: clustered in %.2f s\n", s.label.c_str(), seconds_since(t0));
    }
    return scenes;
}

// The first line of a text file, without its newline; empty when it cannot be read.
std::string first_line(const char* path) {
    std::FILE* f = std::fopen(path, "r");
    if (!f) return {};
    char line[256] = {};
    const bool read = std::fgets(line, sizeof line, f) != nullptr;
    std::fclose(f);
    std::string s = read ? line : "";
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    return s;
}

// How many hardware threads share cpu0's core (Linux sysfs): with two, the top of the thread
// sweep puts two builds on each core and the scaling efficiency there measures the core's
// sharing, not the builder.
std::string core_sharing() {
    const std::string list =
        first_line("/sys/devices/system/cpu/cpu0/topology/thread_siblings_list");
    if (list.empty()) return "threads per core unknown";
    // "0", "0,8" or "0-1": a comma or a range means a sibling.
    const bool shared = list.find_first_of(",-") != std::string::npos;
    return std::string(shared ? "cores shared by SMT siblings" : "one thread per core") +
           " (cpu0 siblings: " + list + ")";
}

// The CPU's model and cpu0's last-level cache with the CPUs that share it: a scene that fits
// one thread's last-level cache but moves between several caches at N threads scales worse.
std::string cpu_description() {
    std::string model = "model unknown";
    if (std::FILE* f = std::fopen("/proc/cpuinfo", "r")) {
        char line[256];
        while (std::fgets(line, sizeof line, f))
            if (std::strncmp(line, "model name", 10) == 0) {
                const char* colon = std::strchr(line, ':');
                model = colon ? colon + 2 : line;
                while (!model.empty() && model.back() == '\n') model.pop_back();
                break;
            }
        std::fclose(f);
    }
    const std::string dir = "/sys/devices/system/cpu/cpu0/cache/index3/";
    const std::string size = first_line((dir + "size").c_str());
    const std::string cpus = first_line((dir + "shared_cpu_list").c_str());
    return model + ", L3 " + (size.empty() ? "unknown" : size + " shared by cpus " + cpus);
}

void usage(const char* argv0) {
    std::fprintf(stderr,
                 "usage: %s [--quick] [--tris N] [--max-threads N] [--mesh PATH] "
                 "[--throughput-only] [--builds-only] [--engine-only] [--repeat N] [--scene TEXT] "
                 "[--thread-cpu] [--cold] [--streaming-objects] [--single-build] [--grain N] "
                 "[--counts LIST] [--sweeps N] [--both-measures]\n",
                 argv0);
}

struct Options {
    bool throughput_only = false, engine_only = false, with_quality = true;
    size_t tris = 1000000;
    int max_threads = std::max(1, int(tbb::info::default_concurrency()));
    std::filesystem::path wuson = ts::assimp_models_dir() / "OBJ/WusonOBJ.obj";
    std::string only_scene;
    int sweeps = 1;              // throughput tables per scene (--sweeps)
    bool both_measures = false;  // each sweep also in session 16's measure (--both-measures)
};

// "1,16" -> {1, 16}: the thread counts of --counts.
std::vector<int> parse_counts(const char* list) {
    std::vector<int> counts;
    for (const char* p = list; *p;) {
        char* end = nullptr;
        counts.push_back(int(std::strtol(p, &end, 10)));
        if (end == p) break;
        p = *end == ',' ? end + 1 : end;
    }
    return counts;
}

// The command line into `o` and the bench's globals; false on an unknown or incomplete option.
bool parse_options(int argc, char** argv, Options& o) {
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        const bool has_value = i + 1 < argc;
        if (a == "--quick")
            o.tris = 100000;
        else if (a == "--tris" && has_value)
            o.tris = std::max<size_t>(1000, std::strtoull(argv[++i], nullptr, 10));
        else if (a == "--max-threads" && has_value)
            o.max_threads = std::max(1, std::atoi(argv[++i]));
        else if (a == "--mesh" && has_value)
            o.wuson = argv[++i];
        else if (a == "--throughput-only")
            o.throughput_only = true;
        else if (a == "--builds-only")
            o.throughput_only = true, o.with_quality = false;
        else if (a == "--engine-only")
            o.engine_only = true;
        else if (a == "--repeat" && has_value)
            g_repeat = std::max(1, std::atoi(argv[++i]));
        else if (a == "--thread-cpu")
            g_thread_cpu = true;
        else if (a == "--cold")
            g_cold = true;
        else if (a == "--streaming-objects")
            g_object_stores = eng::ObjectStores::kStreaming;
        else if (a == "--single-build")
            g_measure.single_build = true;
        else if (a == "--grain" && has_value)
            g_measure.grain = std::max<size_t>(1, std::strtoull(argv[++i], nullptr, 10));
        else if (a == "--counts" && has_value)
            g_counts = parse_counts(argv[++i]);
        else if (a == "--sweeps" && has_value)
            o.sweeps = std::max(1, std::atoi(argv[++i]));
        else if (a == "--both-measures")
            o.both_measures = true;
        else if (a == "--scene" && has_value)
            o.only_scene = argv[++i];
        else
            return false;
    }
    return true;
}

// A scene's throughput tables: --sweeps of them, each in session 16's measure too with
// --both-measures (which of the two goes first alternates), the quality line after the last.
void scene_sweeps(const Scene& s, const Options& o) {
    const Measure chosen = g_measure;
    const int measures = o.both_measures ? 2 : 1;
    for (int r = 0; r < o.sweeps; ++r)
        for (int m = 0; m < measures; ++m) {
            if (o.both_measures) g_measure = (r + m) % 2 == 0 ? kSession16Measure : chosen;
            const bool last = r + 1 == o.sweeps && m + 1 == measures;
            throughput_table(s, o.max_threads, o.with_quality && last);
        }
    g_measure = chosen;
}

// The engine's 1-thread build alone, repeated (--engine-only).
void engine_only_lines(const std::vector<Scene>& scenes) {
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
    }
}

// The machine, the measure's options, and the truncation table's columns.
void print_header() {
    std::printf("bench_engine_clusters: TBB, Embree %s, %u hardware threads, %s\n  CPU: %s%s\n",
                RTC_VERSION_STRING, std::max(1u, unsigned(tbb::info::default_concurrency())),
                core_sharing().c_str(), cpu_description().c_str(),
                g_cold ? "; --cold: inputs and outputs evicted before every timed build" : "");
    if (g_object_stores == eng::ObjectStores::kStreaming)
        std::printf("  --streaming-objects: the engine writes objects with non-temporal stores\n");
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
}

}  // namespace

int main(int argc, char** argv) {
    Options o;
    if (!parse_options(argc, argv, o)) {
        usage(argv[0]);
        return 2;
    }
    const std::vector<Scene> scenes = make_scenes(o.tris, o.wuson, o.only_scene);
    print_header();
    if (o.engine_only) {
        engine_only_lines(scenes);
        return 0;
    }
    for (const Scene& s : scenes) {
        const ts::Bounds b = ts::bounds_of(s.mesh);
        std::vector<ts::TestRay> rays = ts::camera_rays(b, 256, 256, 3);
        const auto rnd = ts::random_rays(b, o.tris < 500000 ? 1 << 15 : 1 << 17, 4);
        rays.insert(rays.end(), rnd.begin(), rnd.end());
        if (!o.throughput_only) truncation_table(s, rays);
        scene_sweeps(s, o);
    }
    return 0;
}
