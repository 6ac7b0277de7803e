// SPDX-License-Identifier: Apache-2.0
// Issue 18, "geometry once": the CLAS traversal, the cluster BLAS traversal and the NV
// traversal (top level, identity instance) run on the same rays over the same triangles and
// must give what a brute-force loop over the engine's one triangle test gives: same
// hit/miss, primitive, t, u, v and facing, bit for bit (every path prepares the same double
// ray and calls the same test; the trees only decide which triangles are tried).
//
// The rays include the cases where the engine's copies of the geometry had drifted:
// - rays through a triangle's vertex at its box corner from far away, where a slab test
//   without the conservative far-distance scaling culls the box (the BLAS traversal's copy
//   did) while the triangle test hits;
// - nearly edge-on triangles seen from a far origin, where facing taken from the sheared
//   edge functions (the CLAS traversal's copy) disagrees with Vulkan's facing, the sign of
//   dot(d, cross(p1 - p0, p2 - p0)) (the NV traversal's copy);
// plus both windings, degenerate and NaN triangles, huge and tiny coordinates, zero
// direction components and a NaN origin.
#include "execute_rig.h"
#include "geometry/box.h"
#include "geometry/slab.h"
#include "geometry/triangle.h"
#include "nv_scene.h"

#include <clastrace/engine/blas.h>
#include <clastrace/engine/nv_trace.h>
#include <clastrace/engine/traversal.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace clastrace::engine::execute_test {
namespace {

namespace geo = geometry;

struct Tri {
    float p[3][3];
};

struct Answer {
    bool hit = false;
    float t = 0, u = 0, v = 0;
    uint32_t primitive = 0;
    bool front = false;
    bool unique = true;  // brute force only: no other triangle hits at the same t
};

geo::PreparedRay prepare(const Ray& ray) {
    const double o[3] = {ray.origin[0], ray.origin[1], ray.origin[2]};
    const double d[3] = {ray.direction[0], ray.direction[1], ray.direction[2]};
    return geo::prepare_ray(o, d, ray.tmin, ray.tmax);
}

// Closest hit over every triangle, lowest index on equal t; `unique` says whether no other
// triangle hits at the same float t (the traversals keep whichever their tree tries first).
Answer brute_force(const std::vector<Tri>& tris, const Ray& ray) {
    Answer best;
    if (!(ray.tmin <= ray.tmax)) return best;
    const geo::PreparedRay r = prepare(ray);
    std::vector<float> hit_t;
    double best_t = 0;
    for (uint32_t i = 0; i < tris.size(); ++i) {
        geo::TriangleHit h;
        if (!geo::intersect_triangle(r, tris[i].p[0], tris[i].p[1], tris[i].p[2], r.tmax, &h))
            continue;
        hit_t.push_back(float(h.t));
        if (best.hit && !(h.t < best_t)) continue;
        best_t = h.t;
        best = Answer{true, float(h.t), float(h.u), float(h.v), i, h.front, true};
    }
    best.unique = std::count(hit_t.begin(), hit_t.end(), best.t) <= 1;
    return best;
}

// The traversals' answers for every ray over one scene (each triangle its own cluster, so
// the BLAS nodes bound single triangles exactly).
struct Traced {
    std::vector<Answer> clas, blas, nv;
    std::vector<std::string> build_findings;
};

Traced trace_all(const std::vector<Tri>& tris, const std::vector<Ray>& rays) {
    Traced out;
    Rig rig(32);
    ClusteredMesh mesh;
    nvtest::GeometrySpec nv_geometry;
    for (uint32_t i = 0; i < tris.size(); ++i) {
        Cluster c;
        for (int k = 0; k < 3; ++k) {
            c.positions.insert(c.positions.end(), tris[i].p[k], tris[i].p[k] + 3);
            nv_geometry.mesh.positions.push_back(
                {tris[i].p[k][0], tris[i].p[k][1], tris[i].p[k][2]});
        }
        c.triangles = {0, 1, 2};
        mesh.clusters.push_back(c);
        nv_geometry.mesh.triangles.push_back({3 * i, 3 * i + 1, 3 * i + 2});
    }
    const std::vector<uint64_t> clas = build_clas(rig, mesh);
    const uint64_t blas = build_blas(rig, clas);
    std::vector<std::vector<std::byte>> clas_bytes;
    for (uint64_t a : clas) clas_bytes.push_back(rig.bytes(a, rig.get<uint32_t>(a + 8)));

    nvtest::BlasSpec spec;
    spec.geometries.push_back(nv_geometry);
    auto nv = nvtest::build_scene({spec}, {nvtest::InstanceSpec{}});
    out.build_findings = nv->findings;
    std::vector<Finding> scene_findings;
    std::string error;
    auto scene = NvScene::open(nv->world.memory, nv->tlas.address, &scene_findings, &error);
    EXPECT_TRUE(scene) << error;

    for (const Ray& ray : rays) {
        Answer a;  // the CLAS traversal, one CLAS per triangle, closest over all
        for (uint32_t i = 0; i < clas_bytes.size(); ++i) {
            const Hit h = trace_closest(std::span<const std::byte>(clas_bytes[i]), ray, 0);
            if (h.hit && (!a.hit || h.t < a.t))
                a = Answer{true, h.t, h.u, h.v, h.cluster_id, h.front_face};
        }
        out.clas.push_back(a);
        const BottomLevelHit b = trace_bottom_level_closest(rig.memory, blas, ray, 0);
        out.blas.push_back(
            b.hit.hit ? Answer{true, b.hit.t, b.hit.u, b.hit.v, b.hit.cluster_id, b.hit.front_face}
                      : Answer{});
        const NvHit n = scene ? scene->closest(ray, 0, 0xFF) : NvHit{};
        out.nv.push_back(n.hit ? Answer{true, n.t, n.u, n.v, n.primitive_index,
                                        n.hit_kind == kHitKindFrontFacing}
                               : Answer{});
    }
    return out;
}

std::string describe(const Answer& a) {
    if (!a.hit) return "miss";
    return "hit " + std::to_string(a.primitive) + " t=" + std::to_string(a.t) +
           " u=" + std::to_string(a.u) + " v=" + std::to_string(a.v) +
           (a.front ? " front" : " back");
}

// Compares one traversal's answer with brute force's; on equal-t ties between triangles
// only t is compared (which of them a tree reports first is its own order).
void expect_same(const Answer& brute, const Answer& got, const char* traversal, size_t ray) {
    SCOPED_TRACE(std::string(traversal) + ", ray " + std::to_string(ray) + ": brute force " +
                 describe(brute) + ", traversal " + describe(got));
    ASSERT_EQ(brute.hit, got.hit);
    if (!brute.hit) return;
    EXPECT_EQ(brute.t, got.t);  // exact: the same test on the same prepared ray
    if (!brute.unique) return;
    EXPECT_EQ(brute.primitive, got.primitive);
    EXPECT_EQ(brute.u, got.u);
    EXPECT_EQ(brute.v, got.v);
    EXPECT_EQ(brute.front, got.front);
}

// Brute force's answers, after checking every traversal against them.
std::vector<Answer> expect_all_agree(const std::vector<Tri>& tris, const std::vector<Ray>& rays) {
    const Traced traced = trace_all(tris, rays);
    EXPECT_TRUE(traced.build_findings.empty()) << traced.build_findings.front();
    std::vector<Answer> brute;
    for (size_t i = 0; i < rays.size(); ++i) {
        brute.push_back(brute_force(tris, rays[i]));
        expect_same(brute[i], traced.clas[i], "CLAS", i);
        expect_same(brute[i], traced.blas[i], "cluster BLAS", i);
        expect_same(brute[i], traced.nv[i], "NV", i);
    }
    return brute;
}

// Deterministic on every platform (no std:: distributions).
struct SplitMix {
    uint64_t s;
    uint64_t next() {
        uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    int64_t between(int64_t lo, int64_t hi) { return lo + int64_t(next() % uint64_t(hi - lo + 1)); }
};

TEST(GeometryOnce, RaysThroughBoxCornersFromFarAwayHitInEveryTraversal) {
    // Integer coordinates, so d = p0 - o is exact and every ray passes exactly through p0,
    // the triangle's vertex at the maximum corner of its box, at t = 1.
    SplitMix rng{18};
    std::vector<Tri> tris;
    std::vector<Ray> rays;
    for (int i = 0; i < 150; ++i) {
        Tri t;
        for (auto& p : t.p)
            for (float& c : p) c = float(rng.between(-1000, 1000));
        for (int a = 0; a < 3; ++a) t.p[0][a] = std::max({t.p[0][a], t.p[1][a], t.p[2][a]});
        tris.push_back(t);
        for (int k = 0; k < 6; ++k) {
            const int64_t far = int64_t(1) << rng.between(10, 23);
            Ray r{};
            for (int a = 0; a < 3; ++a) {
                r.origin[a] = float(rng.between(-far, far));
                r.direction[a] = t.p[0][a] - r.origin[a];
            }
            r.tmin = 0.0f;
            r.tmax = std::numeric_limits<float>::infinity();
            rays.push_back(r);
        }
    }
    const std::vector<Answer> brute = expect_all_agree(tris, rays);
    // The set holds what the drift broke: vertex hits whose box a slab test without the
    // far-distance scaling culls.
    size_t hits = 0, culled_without_scaling = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        if (!brute[i].hit) continue;
        ++hits;
        const Tri& t = tris[i / 6];
        geo::Box box;
        for (const auto& p : t.p) box.grow_point(p);
        double entry;
        const geo::PreparedRay r = prepare(rays[i]);
        EXPECT_TRUE(geo::slab_test<true>(r, box.lo, box.hi, r.tmax, &entry)) << "ray " << i;
        culled_without_scaling += !geo::slab_test<false>(r, box.lo, box.hi, r.tmax, &entry);
    }
    EXPECT_GT(hits, 300u);
    EXPECT_GT(culled_without_scaling, 10u);
}

// Nearly edge-on triangles near the world origin seen from far away. `front` is the sign of
// dot(d, cross(p1 - p0, p2 - p0)) < 0 evaluated exactly (rational arithmetic, GMP, when the
// cases were made); facing from the sheared edge functions gets every one of them wrong.
struct FacingCase {
    float o[3], d[3];
    float p[3][3];
    bool front;
};
const FacingCase kEdgeOnFarAway[] = {
#include "edge_on_cases.inc"
};

TEST(GeometryOnce, FacingOfNearlyEdgeOnTrianglesFollowsVulkan) {
    size_t hits = 0;
    for (const FacingCase& c : kEdgeOnFarAway) {
        Tri t;
        std::memcpy(t.p, c.p, sizeof t.p);
        Ray r{{c.o[0], c.o[1], c.o[2]},
              0.0f,
              {c.d[0], c.d[1], c.d[2]},
              std::numeric_limits<float>::infinity()};
        // Both windings: the reversed triangle faces the other way.
        Tri reversed = t;
        std::memcpy(reversed.p[1], t.p[2], 12);
        std::memcpy(reversed.p[2], t.p[1], 12);
        for (const auto& [tri, front] : {std::pair{t, c.front}, std::pair{reversed, !c.front}}) {
            const std::vector<Answer> brute = expect_all_agree({tri}, {r});
            if (!brute[0].hit) continue;
            ++hits;
            EXPECT_EQ(brute[0].front, front) << "case " << (&c - kEdgeOnFarAway);
        }
    }
    EXPECT_GE(hits, 2 * std::size(kEdgeOnFarAway) - 4);
}

Ray ray(float ox, float oy, float oz, float dx, float dy, float dz, float tmin = 0.0f,
        float tmax = std::numeric_limits<float>::infinity()) {
    return Ray{{ox, oy, oz}, tmin, {dx, dy, dz}, tmax};
}

TEST(GeometryOnce, ExtremesAgreeAcrossTraversals) {
    constexpr float kHuge = 3.0e38f, kTiny = 1.0e-38f,
                    nan = std::numeric_limits<float>::quiet_NaN();
    const std::vector<Tri> tris = {
        {{{-1, -1, 0}, {1, -1, 0}, {0, 1, 0}}},  // 0: counterclockwise seen from +z
        {{{-1, -1, 5}, {0, 1, 5}, {1, -1, 5}}},  // 1: clockwise seen from +z
        {{{-kHuge, -kHuge, 10}, {kHuge, -kHuge, 10}, {0, kHuge, 10}}},  // 2: huge
        {{{-kTiny, -kTiny, -3}, {kTiny, -kTiny, -3}, {0, kTiny, -3}}},  // 3: tiny
        {{{0, 0, 20}, {1, 1, 20}, {2, 2, 20}}},                         // 4: degenerate (collinear)
        {{{4, 4, 20}, {4, 4, 20}, {5, 4, 20}}},      // 5: degenerate (repeated vertex)
        {{{8, 8, 30}, {nan, 9, 30}, {9, 8, 30}}},    // 6: NaN vertex
        {{{100, 0, -1}, {100, 0, 1}, {100, 2, 0}}},  // 7: in the plane x = 100
    };
    const std::vector<Ray> rays = {
        ray(0, 0, 50, 0, 0, -1),                    // through 2, 1, 0 down the z axis
        ray(0, 0, -50, 0, 0, 1),                    // up: 3 first
        ray(0, -0.5f, 2, 0, 0, -1),                 // 0 from above
        ray(0, -0.5f, -2, 0, 0, 1),                 // 0 from below
        ray(0, 0, 7, 0, 0, 1),                      // only 2
        ray(0, 0, 7, 0, 0, 1, 0, 2.0f),             // 2 out of reach
        ray(0, 0, 7, 0, 0, 1, 3.0f, 3.0f),          // t exactly 3: closed interval
        ray(1, 1, 25, 0, 0, -1),                    // through the collinear one
        ray(4.5f, 4, 25, 0, 0, -1),                 // through the repeated-vertex one
        ray(8.5f, 8.2f, 35, 0, 0, -1),              // through the NaN one
        ray(50, 1, 0, 1, 0, 0),                     // 7 head on
        ray(100, -5, 0, 0, 1, 0),                   // 7 edge-on, in its plane
        ray(0, -1, 3, 0, 0, -1),                    // along the edge y = -1 of 0 and 1
        ray(-1, -1, 3, 0, 0, -1),                   // through their shared vertex
        ray(0, 0, 0, 0, 0, 0),                      // zero direction
        ray(nan, 0, 50, 0, 0, -1),                  // NaN origin
        ray(0, 0, 50, 0, 0, -1, 1.0f, 0.5f),        // empty interval
        ray(-kHuge, -kHuge, 20, kHuge, kHuge, -1),  // huge direction
        ray(0, 0, 1e30f, 1e-30f, 0, -1),            // tiny component from far away
    };
    const std::vector<Answer> brute = expect_all_agree(tris, rays);
    // Triangle 0 is counterclockwise seen from +z: dot(d, cross(p1 - p0, p2 - p0)) < 0 for a
    // ray going down, so front-facing from above and back-facing from below.
    ASSERT_TRUE(brute[2].hit);
    EXPECT_EQ(brute[2].primitive, 0u);
    EXPECT_TRUE(brute[2].front);
    ASSERT_TRUE(brute[3].hit);
    EXPECT_FALSE(brute[3].front);
    ASSERT_TRUE(brute[0].hit);
    EXPECT_EQ(brute[0].primitive, 2u);
    EXPECT_TRUE(brute[6].hit);
    // Through the collinear, repeated-vertex and NaN triangles onto the huge one below.
    for (size_t i : {7, 8, 9}) EXPECT_EQ(brute[i].primitive, 2u) << "ray " << i;
    for (size_t i : {11, 14, 15, 16}) EXPECT_FALSE(brute[i].hit) << "ray " << i;
}

}  // namespace
}  // namespace clastrace::engine::execute_test
