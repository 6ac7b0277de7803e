// SPDX-License-Identifier: Apache-2.0
// Closed meshes leak nowhere: rays aimed exactly at shared edges (midpoints and other sample
// points) and vertices, from inside and from outside, always hit before passing the target
// point, across cluster boundaries too, with and without position truncation. Shared
// vertices are truncated identically, so the mesh stays closed under truncation.
#include "clastrace/testsupport/cluster_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <set>
#include <sstream>
#include <functional>

namespace ts = clastrace::testsupport;

namespace {

struct Shape {
    ts::TriangleMesh mesh;
    // A point strictly inside the closed surface "behind" surface point p: the segment from
    // it to p crosses the surface only at p.
    std::function<ts::Float3(const ts::Float3& p, int variant)> inside_point;
};

std::array<double, 3> sub(const ts::Float3& a, const ts::Float3& b) {
    return {double(a[0]) - b[0], double(a[1]) - b[1], double(a[2]) - b[2]};
}

struct LeakCounts {
    size_t rays = 0, leaks = 0;
    std::vector<std::string> examples;
};

// Shoots origin -> target with the unnormalized direction target - origin, so the surface is
// met at t ~= 1; anything beyond 1 + 1e-4 would be another part of the surface, i.e. a leak.
void shoot(const ts::ClusterScene& scene, const ts::Float3& origin, const ts::Float3& target,
           LeakCounts& out) {
    ts::TestRay r;
    r.origin = origin;
    const auto d = sub(target, origin);
    r.direction = {float(d[0]), float(d[1]), float(d[2])};
    r.tmin = 0.0f;
    r.tmax = 1.0001f;
    ++out.rays;
    const ts::SceneHit h = ts::trace_scene(scene, r);
    if (!h.hit) {
        ++out.leaks;
        if (out.examples.size() < 5) {
            std::ostringstream s;
            s.precision(9);
            s << "leak: o=(" << origin[0] << "," << origin[1] << "," << origin[2] << ") target=("
              << target[0] << "," << target[1] << "," << target[2] << ")";
            out.examples.push_back(s.str());
        }
    }
}

LeakCounts leak_check(const Shape& shape, unsigned truncate_bits) {
    const ts::TriangleMesh& m = shape.mesh;
    const auto clusters = ts::build_clusters(m, 64, 124);
    const ts::ClusterScene scene = ts::build_cluster_scene(m, clusters, {1, 0, 0, truncate_bits});
    EXPECT_EQ(scene.failed_builds, 0u);
    std::vector<ts::Float3> p(m.positions.size());
    for (size_t i = 0; i < p.size(); ++i)
        p[i] = ts::truncate_position(m.positions[i], truncate_bits);

    std::set<std::pair<uint32_t, uint32_t>> edges;
    for (const ts::Triangle& t : m.triangles)
        for (int k = 0; k < 3; ++k) edges.insert(std::minmax(t[k], t[(k + 1) % 3]));

    std::vector<ts::Float3> targets;
    for (const ts::Float3& v : p) targets.push_back(v);  // exactly at the shared vertex
    const float fractions[] = {0.5f, 0.25f, 0.75f, 1.0f / 3.0f, 0.001f, 0.999f};
    for (const auto& [a, b] : edges)
        for (float s :
             fractions)  // points on the edge, in float as an application would compute them
            targets.push_back({p[a][0] + s * (p[b][0] - p[a][0]), p[a][1] + s * (p[b][1] - p[a][1]),
                               p[a][2] + s * (p[b][2] - p[a][2])});

    LeakCounts counts;
    for (const ts::Float3& target : targets)
        for (int variant = 0; variant < 3; ++variant) {
            const ts::Float3 in = shape.inside_point(target, variant);
            shoot(scene, in, target, counts);  // inside -> out
            const ts::Float3 out{2 * target[0] - in[0], 2 * target[1] - in[1],
                                 2 * target[2] - in[2]};
            shoot(scene, out, target, counts);  // outside -> in
        }
    return counts;
}

Shape icosphere() {
    return {ts::make_icosphere(3, 1.5f), [](const ts::Float3& p, int variant) -> ts::Float3 {
                // The centre, and two interior points off-centre (the sphere is convex).
                const float off[3][3] = {{0, 0, 0}, {0.3f, -0.2f, 0.1f}, {-0.25f, 0.1f, 0.35f}};
                (void)p;
                return {off[variant][0], off[variant][1], off[variant][2]};
            }};
}

Shape torus() {
    const float R = 2.0f, r = 0.6f;
    return {ts::make_torus(40, 20, R, r), [R](const ts::Float3& p, int variant) -> ts::Float3 {
                // The tube's centre circle at p's angle, nudged within the tube's cross-section:
                // the meridian half-plane holds the whole segment to p.
                const double u = std::atan2(p[1], p[0]);
                const double radial[3] = {0.0, 0.2, -0.15}, up[3] = {0.0, 0.1, -0.2};
                const double rr = R + radial[variant];
                return {float(rr * std::cos(u)), float(rr * std::sin(u)), float(up[variant])};
            }};
}

class Watertight : public ::testing::TestWithParam<unsigned> {};

TEST_P(Watertight, NoRayThroughSharedEdgesOrVerticesLeaks) {
    const unsigned bits = GetParam();
    for (const Shape& shape : {icosphere(), torus()}) {
        const LeakCounts c = leak_check(shape, bits);
        std::cout << "[watertight] " << shape.mesh.name << " truncate " << bits << ": rays "
                  << c.rays << ", leaks " << c.leaks << "\n";
        for (const auto& e : c.examples) std::cout << "    " << e << "\n";
        EXPECT_EQ(c.leaks, 0u) << shape.mesh.name << " truncate " << bits;
        EXPECT_GT(c.rays, 10000u);
    }
}

INSTANTIATE_TEST_SUITE_P(TruncateBits, Watertight, ::testing::Values(0u, 8u, 16u));

// The leak check can fail: the same sphere with one triangle removed leaks.
TEST(WatertightSelfCheck, AHoleIsSeen) {
    Shape holed = icosphere();
    holed.mesh.triangles.erase(holed.mesh.triangles.begin() + 100);
    const LeakCounts c = leak_check(holed, 0);
    EXPECT_GT(c.leaks, 0u);
}

// A quad split along its diagonal, as two clusters: rays exactly through the diagonal and the
// shared corners hit, at scales from denormal to near FLT_MAX.
TEST(WatertightExtremes, DiagonalOfSplitQuadAtEveryScale) {
    for (float scale : {1e-40f, 1e-38f, 1e-20f, 1.0f, 1e20f, 1e38f, 3.0e38f}) {
        ts::TriangleMesh m;
        m.name = "quad";
        m.positions = {{-scale, -scale, 0},
                       {scale, -scale, 0},
                       {scale, scale, 0},
                       {-scale, scale, 0}};
        m.triangles = {{0, 1, 2}, {0, 2, 3}};
        std::vector<ts::MeshCluster> clusters(2);
        clusters[0].vertices = {0, 1, 2};
        clusters[0].triangles = {{0, 1, 2}};
        clusters[0].mesh_triangles = {0};
        clusters[1].vertices = {0, 2, 3};
        clusters[1].triangles = {{0, 1, 2}};
        clusters[1].mesh_triangles = {1};
        const ts::ClusterScene scene = ts::build_cluster_scene(m, clusters, {});
        ASSERT_EQ(scene.failed_builds, 0u);
        size_t rays = 0, leaks = 0;
        for (int i = 0; i <= 64; ++i) {
            const float s = scale * (float(i) / 32 - 1.0f);  // on the diagonal x == y
            for (float dir : {1.0f, -1.0f}) {
                ts::TestRay r;
                r.origin = {s, s, -dir * scale};
                r.direction = {0, 0, dir * scale};
                ++rays;
                if (!ts::trace_scene(scene, r).hit) ++leaks;
            }
        }
        EXPECT_EQ(leaks, 0u) << "scale " << scale << " of " << rays << " rays";
    }
}

}  // namespace
