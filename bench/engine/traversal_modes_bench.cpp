// SPDX-License-Identifier: Apache-2.0
// The trade between the engine's two traversal modes (engine::TraversalMode, double and
// float32), measured: per extremes scene, closest-hit Mrays/s on one thread (wall and CPU)
// next to Embree 3 in robust mode on the same NV scene, the disagreements with Embree off
// ties, and per mode the disagreements with the driver traces' ray checks.
//
// A tie (counted apart, never a disagreement) is one of:
// - t-tie: both hit, other instance or primitive, and |t_engine - t_embree| <= tie_t, where
//   tie_t = 2 * NvHit::t_error + 8 ulps of t (each side's float32 error bound: the same
//   surface point found on two primitives, shared edges and coplanar overlaps);
// - edge-tie: hit/miss or primitive differs, and every hit reported lies on an edge or
//   vertex of its triangle: min(u, v, 1 - u - v) <= max(NvHit::uv_error, 1e-5) (a ray
//   through an edge that the two watertight tests round to either side).
// A disagreement is any other difference, and a same-primitive hit whose t differs by more
// than tie_t.
//
// Usage: traversal_modes_bench [--rays N] [--traces DIR]  (N default 1000000 per scene; DIR
// holds the .clt driver traces, default traces/samples of the source tree when present).
#include "nv_scene.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <cfloat>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <functional>
#include <random>
#include <string>
#include <vector>

using namespace clastrace;
using namespace clastrace::nvtest;

namespace {

constexpr eng::TraversalMode kModes[] = {eng::TraversalMode::kDouble, eng::TraversalMode::kFloat32};
constexpr uint32_t kFlagCycle[] = {0, eng::kRayFlagCullBackFacingTriangles,
                                   eng::kRayFlagCullFrontFacingTriangles};

// Wall and process CPU seconds, accumulated over the timed chunks of one pass.
struct Stopwatch {
    double wall = 0, cpu = 0;
    std::chrono::steady_clock::time_point w0;
    std::clock_t c0 = 0;
    void start() {
        w0 = std::chrono::steady_clock::now();
        c0 = std::clock();
    }
    void stop() {
        wall += std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
        cpu += double(std::clock() - c0) / CLOCKS_PER_SEC;
    }
};

struct Scene {
    const char* name;
    std::vector<BlasSpec> blas;
    std::vector<InstanceSpec> instances;
    float radius;    // rays aim at a point inside [-radius, radius]^3
    float distance;  // from an origin this far from 0 in a random direction
};

BlasSpec triangles(ts::TriangleMesh mesh, uint32_t flags = VK_GEOMETRY_OPAQUE_BIT_NV) {
    BlasSpec s;
    s.geometries.push_back({std::move(mesh), {}, flags});
    return s;
}

ts::TriangleMesh scaled(ts::TriangleMesh m, float s) {
    for (auto& p : m.positions)
        for (float& x : p) x *= s;
    return m;
}

// `count` closed boxes of `size` x `size` x `thickness`, randomly turned, centres inside
// [-1, 1]^3: two faces 0.01 apart, the "thin slab" the driver traces caught.
ts::TriangleMesh thin_slabs(size_t count, float size, float thickness, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    ts::TriangleMesh m;
    static constexpr uint32_t kFaces[12][3] = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6},
                                               {0, 1, 4}, {1, 5, 4}, {2, 6, 3}, {3, 6, 7},
                                               {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    for (size_t i = 0; i < count; ++i) {
        // A random orthonormal frame from two random vectors (Gram-Schmidt).
        float a[3] = {u(rng), u(rng), u(rng)}, b[3] = {u(rng), u(rng), u(rng)};
        const float la = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) + 1e-6f;
        for (float& x : a) x /= la;
        const float ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        for (int k = 0; k < 3; ++k) b[k] -= ab * a[k];
        const float lb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]) + 1e-6f;
        for (float& x : b) x /= lb;
        const float c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                            a[0] * b[1] - a[1] * b[0]};
        const float centre[3] = {u(rng), u(rng), u(rng)};
        const uint32_t base = uint32_t(m.positions.size());
        for (int corner = 0; corner < 8; ++corner) {
            const float sa = (corner & 1 ? 0.5f : -0.5f) * size;
            const float sb = (corner & 2 ? 0.5f : -0.5f) * size;
            const float sc = (corner & 4 ? 0.5f : -0.5f) * thickness;
            m.positions.push_back({centre[0] + sa * a[0] + sb * b[0] + sc * c[0],
                                   centre[1] + sa * a[1] + sb * b[1] + sc * c[1],
                                   centre[2] + sa * a[2] + sb * b[2] + sc * c[2]});
        }
        for (const auto& f : kFaces) m.triangles.push_back({base + f[0], base + f[1], base + f[2]});
    }
    return m;
}

// 1e-2-scaled instances of the slabs, every other one mirrored, some with flipped facing or
// facing culls disabled, packed inside [-0.02, 0.02]^3.
std::vector<InstanceSpec> scaled_mirrored_instances(size_t count, uint64_t seed) {
    std::vector<InstanceSpec> out = random_instances(count, 1, 0.02f, seed);
    for (size_t i = 0; i < out.size(); ++i) {
        InstanceSpec& s = out[i];
        for (int r = 0; r < 3; ++r)
            for (int k = 0; k < 3; ++k) s.transform[4 * r + k] *= 1e-2f;
        if (i % 2)
            for (int r = 0; r < 3; ++r) s.transform[4 * r] = -s.transform[4 * r];
        s.mask = 0xFF;
        s.flags &= ~uint32_t(VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_NV);
    }
    return out;
}

// A soup with a NaN vertex in every 7th triangle and every 5th collapsed onto a line.
ts::TriangleMesh nan_degenerate_soup(size_t count, uint64_t seed) {
    ts::TriangleMesh m = ts::make_random_soup(count, seed, 1.0f, 0.1f);
    for (size_t i = 0; i < m.triangles.size(); ++i) {
        auto& p = m.positions;
        const auto& t = m.triangles[i];
        if (i % 7 == 0) p[t[1]][0] = std::nanf("");
        if (i % 5 == 0)
            for (int k = 0; k < 3; ++k) p[t[2]][k] = 0.5f * (p[t[0]][k] + p[t[1]][k]);
    }
    return m;
}

std::vector<Scene> extremes_scenes() {
    std::vector<Scene> s;
    const InstanceSpec identity;
    s.push_back({"huge-1e30",
                 {triangles(scaled(ts::make_icosphere(5, 1.0f), 1e30f))},
                 {identity},
                 1e30f,
                 3e30f});
    s.push_back({"tiny-1e-30",
                 {triangles(scaled(ts::make_icosphere(5, 1.0f), 1e-30f))},
                 {identity},
                 1e-30f,
                 3e-30f});
    s.push_back({"1e-3-tris-at-4e4",
                 {triangles(ts::make_random_soup(200000, 7, 0.25f, 1e-3f))},
                 {identity},
                 0.25f,
                 4e4f});
    s.push_back(
        {"thin-slabs", {triangles(thin_slabs(4000, 0.3f, 0.01f, 3))}, {identity}, 1.0f, 3.0f});
    s.push_back({"slabs-1e-2-mirrored",
                 {triangles(thin_slabs(400, 0.3f, 0.01f, 5))},
                 scaled_mirrored_instances(64, 11),
                 0.03f,
                 0.1f});
    s.push_back(
        {"nan-degenerate", {triangles(nan_degenerate_soup(100000, 9))}, {identity}, 1.0f, 3.0f});
    return s;
}

// Ray i of a scene: from `distance` away in a random direction towards a random point of
// [-radius, radius]^3, the whole ray interval, flags cycling through no cull and each cull.
struct RaySource {
    std::mt19937_64 rng;
    const Scene& scene;
    eng::Ray next() {
        std::normal_distribution<double> n(0.0, 1.0);
        std::uniform_real_distribution<double> u(-1.0, 1.0);
        double out[3] = {n(rng), n(rng), n(rng)};
        const double len = std::sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2]);
        eng::Ray r{};
        double d[3], dl = 0;
        for (int k = 0; k < 3; ++k) {
            r.origin[k] = float(out[k] / len * scene.distance);
            d[k] = u(rng) * scene.radius - double(r.origin[k]);
            dl += d[k] * d[k];
        }
        for (int k = 0; k < 3; ++k) r.direction[k] = float(d[k] / std::sqrt(dl));
        r.tmin = 0.0f;
        r.tmax = FLT_MAX;
        return r;
    }
};

bool on_edge(float u, float v, float uv_error) {
    return std::min({u, v, 1.0f - u - v}) <= std::max(uv_error, 1e-5f);
}

struct Verdicts {
    size_t rays = 0, hits = 0, agree = 0, t_tie = 0, edge_tie = 0, disagree = 0;
    size_t cancellation = 0;  // of `disagree`: explained by the origin's rounding (below)
};

// Why two float32 tracers may answer differently for the same float inputs: both move the
// triangle to the ray origin in float (Woop's shear; Embree's robust test), so each vertex
// moves by up to half an ulp of the origin's largest object-space coordinate. A triangle whose
// extent is below kCancellationUlps such ulps is a different triangle to each of them (the
// 1e-3-tris-at-4e4 scene: ulp(4e4) = 0.0039, four times the triangles' size), and neither
// answer is the exact one; the double mode's is.
constexpr double kCancellationUlps = 4.0;

class OriginRounding {
public:
    explicit OriginRounding(const Scene& s) : scene_(s) {}
    // Whether the hit's triangle is within the origin's rounding for ray `r`.
    bool explains(const eng::Ray& r, uint32_t instance, uint32_t geometry,
                  uint32_t primitive) const {
        if (instance >= scene_.instances.size()) return false;
        const InstanceSpec& in = scene_.instances[instance];
        if (in.blas < 0 || size_t(in.blas) >= scene_.blas.size()) return false;
        const BlasSpec& b = scene_.blas[size_t(in.blas)];
        if (geometry >= b.geometries.size()) return false;
        const ts::TriangleMesh& m = b.geometries[geometry].mesh;
        if (primitive >= m.triangles.size()) return false;
        double extent = 0;
        for (int a = 0; a < 3; ++a)
            for (int k = 0; k < 3; ++k) {
                const auto& p = m.positions[m.triangles[primitive][a]];
                const auto& q = m.positions[m.triangles[primitive][(a + 1) % 3]];
                extent = std::max(extent, std::fabs(double(p[k]) - double(q[k])));
            }
        const double o = object_origin_size(in, r);
        return kCancellationUlps * o * FLT_EPSILON >= extent;
    }

private:
    // The largest coordinate of the ray origin in the instance's object space (the transform's
    // 3x3 part inverted in double).
    static double object_origin_size(const InstanceSpec& in, const eng::Ray& r) {
        const float* t = in.transform;
        double d[3];
        for (int k = 0; k < 3; ++k) d[k] = double(r.origin[k]) - double(t[4 * k + 3]);
        const double a = t[0], b = t[1], c = t[2], e = t[4], f = t[5], g = t[6], h = t[8], i = t[9],
                     j = t[10];
        const double det = a * (f * j - g * i) - b * (e * j - g * h) + c * (e * i - f * h);
        if (det == 0 || !std::isfinite(det)) return 0;
        const double o[3] = {
            ((f * j - g * i) * d[0] - (b * j - c * i) * d[1] + (b * g - c * f) * d[2]) / det,
            (-(e * j - g * h) * d[0] + (a * j - c * h) * d[1] - (a * g - c * e) * d[2]) / det,
            ((e * i - f * h) * d[0] - (a * i - b * h) * d[1] + (a * f - b * e) * d[2]) / det};
        return std::max({std::fabs(o[0]), std::fabs(o[1]), std::fabs(o[2])});
    }
    const Scene& scene_;
};

void classify(Verdicts& v, const eng::NvHit& e, const RefHit& r);

// A disagreement, classed: the origin's rounding explains it when a triangle either side hit is
// within it.
void classify_ray(Verdicts& v, const OriginRounding& rounding, const eng::Ray& ray,
                  const eng::NvHit& e, const RefHit& r) {
    const size_t before = v.disagree;
    classify(v, e, r);
    if (v.disagree == before) return;
    if ((e.hit && rounding.explains(ray, e.instance_index, e.geometry_index, e.primitive_index)) ||
        (r.hit && rounding.explains(ray, r.instance, r.geometry, r.primitive)))
        ++v.cancellation;
}

void classify(Verdicts& v, const eng::NvHit& e, const RefHit& r) {
    ++v.rays;
    v.hits += e.hit;
    if (!e.hit && !r.hit) {
        ++v.agree;
        return;
    }
    const double tie_t = e.hit ? 2.0 * e.t_error + 8.0 * FLT_EPSILON * std::fabs(double(e.t)) : 0.0;
    if (e.hit && r.hit && std::fabs(double(e.t) - double(r.t)) <= tie_t) {
        const bool same = e.instance_index == r.instance && e.geometry_index == r.geometry &&
                          e.primitive_index == r.primitive;
        if (!same)
            ++v.t_tie;
        else
            ++(e.hit_kind == r.hit_kind ? v.agree : v.disagree);  // facing must agree
        return;
    }
    const bool engine_edge = !e.hit || on_edge(e.u, e.v, e.uv_error);
    const bool embree_edge = !r.hit || on_edge(r.u, r.v, e.uv_error);
    ++(engine_edge && embree_edge && (e.hit || r.hit) ? v.edge_tie : v.disagree);
}

struct ModeRun {
    Stopwatch time;
    Verdicts verdicts;
};

void print_scene(const Scene& s, size_t ray_count, const Stopwatch& embree, const ModeRun* runs) {
    const double mrays = double(ray_count) / 1e6;
    for (size_t m = 0; m < std::size(kModes); ++m) {
        const ModeRun& r = runs[m];
        const Verdicts& v = r.verdicts;
        std::printf(
            "%-20s %-7s %8zu %7zu | %7.3f %7.3f | %7.3f %7.3f | %6.2f %6.2f | %7zu %7zu %7zu "
            "%7zu\n",
            m == 0 ? s.name : "", eng::traversal_mode_name(kModes[m]), v.rays, v.hits,
            mrays / r.time.wall, mrays / r.time.cpu, mrays / embree.wall, mrays / embree.cpu,
            embree.wall / r.time.wall, embree.cpu / r.time.cpu, v.disagree, v.t_tie, v.edge_tie,
            v.cancellation);
    }
}

// Every ray through both engine modes and Embree, timed apart in chunks of 65536 (so the
// answers never fill memory), then compared.
void run_scene(const Scene& s, size_t ray_count) {
    auto built = build_scene(s.blas, s.instances);
    std::string error;
    std::vector<eng::Finding> findings;
    auto scene = eng::NvScene::open(built->world.memory, built->tlas.address, &findings, &error);
    if (!scene) {
        std::fprintf(stderr, "%s: the engine's scene did not open: %s\n", s.name, error.c_str());
        std::exit(1);
    }
    const EmbreeNvScene embree(s.blas, s.instances);
    RaySource source{std::mt19937_64(1234), s};
    const OriginRounding rounding(s);
    ModeRun runs[std::size(kModes)];
    Stopwatch embree_time;
    constexpr size_t kChunk = 65536;
    std::vector<eng::Ray> rays;
    std::vector<eng::NvHit> engine_hits[std::size(kModes)];
    std::vector<RefHit> embree_hits;
    for (size_t done = 0; done < ray_count; done += rays.size()) {
        rays.clear();
        for (size_t i = 0; i < std::min(kChunk, ray_count - done); ++i)
            rays.push_back(source.next());
        for (size_t m = 0; m < std::size(kModes); ++m) {
            engine_hits[m].resize(rays.size());
            runs[m].time.start();
            for (size_t i = 0; i < rays.size(); ++i)
                engine_hits[m][i] =
                    scene->closest(rays[i], kFlagCycle[(done + i) % 3], 0xFF, kModes[m]);
            runs[m].time.stop();
        }
        embree_hits.resize(rays.size());
        embree_time.start();
        for (size_t i = 0; i < rays.size(); ++i)
            embree_hits[i] = embree.closest(rays[i], kFlagCycle[(done + i) % 3], 0xFF);
        embree_time.stop();
        for (size_t m = 0; m < std::size(kModes); ++m)
            for (size_t i = 0; i < rays.size(); ++i)
                classify_ray(runs[m].verdicts, rounding, rays[i], engine_hits[m][i],
                             embree_hits[i]);
    }
    print_scene(s, ray_count, embree_time, runs);
}

// The ray checks of every .clt in `dir` replayed in each mode: rays, disagreements, ties.
void run_driver_traces(const std::filesystem::path& dir) {
    std::vector<std::filesystem::path> files;
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(dir, ec))
        if (entry.path().extension() == ".clt") files.push_back(entry.path());
    std::sort(files.begin(), files.end());
    std::printf("\nDriver traces (%s): ray checks replayed per mode\n", dir.c_str());
    std::printf("%-32s %-7s %7s %7s %9s %7s %7s\n", "trace", "mode", "checks", "rays", "disagree",
                "tie", "edge");
    for (const auto& file : files) {
        for (eng::TraversalMode mode : kModes) {
            traces::TraceError err;
            auto reader = traces::TraceReader::open(file.string(), &err);
            if (!reader) {
                std::fprintf(stderr, "%s: %s\n", file.c_str(), err.message.c_str());
                std::exit(2);
            }
            replay::ReplayOptions options;
            options.check_hazards = false;
            options.ray_check_traversal = mode == eng::TraversalMode::kFloat32
                                              ? replay::RayCheckTraversal::kFloat32
                                              : replay::RayCheckTraversal::kDouble;
            const auto report = replay::replay_trace(*reader, file.string(), options);
            uint64_t checks = 0, rays = 0, disagree = 0, tie = 0, edge = 0;
            for (const auto& c : report.ray_checks) {
                if (!c.checked) continue;
                ++checks;
                rays += c.rays;
                disagree += c.disagree;
                tie += c.tie;
                edge += c.edge;
            }
            if (!checks) break;  // no ray checks in this trace: no row
            std::printf("%-32s %-7s %7llu %7llu %9llu %7llu %7llu\n", file.filename().c_str(),
                        eng::traversal_mode_name(mode), (unsigned long long)checks,
                        (unsigned long long)rays, (unsigned long long)disagree,
                        (unsigned long long)tie, (unsigned long long)edge);
        }
    }
}

int usage() {
    std::fprintf(stderr, "usage: traversal_modes_bench [--rays N] [--traces DIR]\n");
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    size_t ray_count = 1000000;
    std::filesystem::path traces_dir = CLASTRACE_SAMPLE_TRACES_DIR;
    for (int i = 1; i < argc; ++i) {
        if (!std::strcmp(argv[i], "--rays") && i + 1 < argc) {
            char* end = nullptr;
            ray_count = std::strtoull(argv[++i], &end, 10);
            if (!ray_count || *end) return usage();
        } else if (!std::strcmp(argv[i], "--traces") && i + 1 < argc) {
            traces_dir = argv[++i];
        } else {
            return usage();
        }
    }
    std::printf(
        "Traversal modes on the extremes scenes: closest hit, 1 thread, %zu rays per scene\n"
        "Embree 3 robust (RTC_SCENE_FLAG_ROBUST) on the same NV scene is the peer; x: Embree "
        "time / engine time\n(above 1: engine faster). Ties (t-tie, edge-tie) are counted "
        "apart from disagreements (header of bench/engine/traversal_modes_bench.cpp);\n"
        "origin: the disagreements that the origin's float rounding explains (a triangle hit "
        "on either side\nis smaller than 4 ulps of the ray origin in object space).\n",
        ray_count);
    std::printf("%-20s %-7s %8s %7s | %7s %7s | %7s %7s | %6s %6s | %7s %7s %7s %7s\n", "scene",
                "mode", "rays", "hits", "engine", "", "Embree", "", "x", "", "disagr", "t-tie",
                "edge", "origin");
    std::printf("%-20s %-7s %8s %7s | %7s %7s | %7s %7s | %6s %6s |\n", "", "", "", "", "Mray/s",
                "CPU", "Mray/s", "CPU", "wall", "CPU");
    for (const Scene& s : extremes_scenes()) run_scene(s, ray_count);
    if (std::filesystem::is_directory(traces_dir)) {
        run_driver_traces(traces_dir);
    } else {
        std::printf("\nDriver traces: no directory %s (--traces DIR)\n", traces_dir.c_str());
    }
    return 0;
}
