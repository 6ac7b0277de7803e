// SPDX-License-Identifier: Apache-2.0
// The cluster traversals (one CLAS: trace_closest; a cluster BLAS: trace_bottom_level_bytes)
// against their exhaustive references (every triangle tested, no box), in both traversal
// modes: the same hit, t, barycentrics, triangle, cluster, geometry, facing and reference on
// random rays, rays aimed at vertices and edge midpoints (points on leaf boxes' faces, where
// two triangles tie), axis-parallel rays, and scenes at the extremes (1e30, 1e-30, near
// FLT_MAX, 1e-3 triangles seen from 4e4, NaN and degenerate triangles, truncated positions).
#include "clastrace/engine/blas.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "clastrace/testsupport/cluster_scene.h"
#include "clastrace/testsupport/clusters.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <sstream>

namespace ts = clastrace::testsupport;
namespace eng = clastrace::engine;

namespace {

constexpr uint64_t kClasStride = 0x10000;  // cluster c lives at (c + 1) * kClasStride

struct ReferenceCase {
    const char* name;
    std::function<ts::TriangleMesh()> mesh;
    uint32_t truncate_bits = 0;
    float ray_distance = 0.0f;  // 0: 1.5x the bounding diagonal
    float scale = 1.0f;         // applied after clustering (the clusterer wants moderate sizes)
};

ts::TriangleMesh scaled(ts::TriangleMesh mesh, float scale) {
    for (auto& p : mesh.positions)
        for (float& c : p) c *= scale;
    return mesh;
}

// A soup with NaN vertices, zero-area and sliver triangles mixed in.
ts::TriangleMesh nan_and_degenerate_soup() {
    ts::TriangleMesh mesh = ts::make_random_soup(3000, 31, 4.0f, 1.0f);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (size_t t = 0; t < mesh.triangles.size(); t += 7) {
        auto& tri = mesh.triangles[t];
        if (t % 3 == 0) tri[1] = tri[0];  // zero area
        if (t % 3 == 1) mesh.positions[tri[2]][1] = nan;
        if (t % 3 == 2) {  // sliver: v2 on the line v0-v1
            for (int k = 0; k < 3; ++k)
                mesh.positions[tri[2]][k] =
                    0.5f * (mesh.positions[tri[0]][k] + mesh.positions[tri[1]][k]);
        }
    }
    return mesh;
}

const ReferenceCase kCases[] = {
    {"icosphere", [] { return ts::make_icosphere(4, 1.0f); }},
    {"torus_trunc12", [] { return ts::make_torus(64, 32, 1.0f, 0.35f); }, 12},
    {"terrain", [] { return ts::make_terrain(60, 60, 3); }},
    {"random_soup", [] { return ts::make_random_soup(6000, 11, 10.0f, 2.0f); }},
    {"sphere_at_1e30", [] { return ts::make_icosphere(3, 1.0f); }, 0, 0.0f, 1e30f},
    {"sphere_at_1e_minus_30", [] { return ts::make_icosphere(3, 1.0f); }, 0, 0.0f, 1e-30f},
    {"sphere_near_flt_max", [] { return ts::make_icosphere(3, 1.0f); }, 0, 0.0f, 1e38f},
    {"tiny_tris_seen_from_4e4", [] { return ts::make_random_soup(3000, 17, 1.0f, 1e-3f); }, 0,
     4e4f},
    {"nan_and_degenerate", nan_and_degenerate_soup},
};

struct Rays {
    std::vector<eng::Ray> rays;
    std::vector<uint32_t> flags;
};

// Random rays, rays at vertices and edge midpoints of the stored (truncated) triangles from
// random directions, and axis-parallel rays at vertices.
Rays make_rays(const ts::ClusterScene& scene, const ReferenceCase& c, uint64_t seed) {
    ts::Bounds box;
    for (const ts::Bounds& b : scene.bounds) {
        box.extend(b.lo);
        box.extend(b.hi);
    }
    double diag = 0;  // in double: near FLT_MAX the float diagonal overflows
    for (int k = 0; k < 3; ++k) diag += std::pow(double(box.hi[k]) - double(box.lo[k]), 2.0);
    diag = std::sqrt(diag);
    const double distance = c.ray_distance > 0 ? c.ray_distance : 1.5 * diag;
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> gauss;
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    Rays out;
    auto add = [&](const double target[3], const double d[3], double dist) {
        eng::Ray r{};
        for (int k = 0; k < 3; ++k) {
            r.origin[k] = float(target[k] - d[k] * dist);
            r.direction[k] = float(d[k]);
        }
        r.tmin = 0.0f;
        r.tmax = std::numeric_limits<float>::max();
        out.rays.push_back(r);
        // Every fourth ray culls back faces: the flag rules must agree too.
        out.flags.push_back(out.rays.size() % 4 == 0 ? eng::kRayFlagCullBackFacingTriangles
                                                     : eng::kRayFlagNone);
    };
    auto random_direction = [&](double d[3]) {
        double n = 0;
        for (int k = 0; k < 3; ++k) {
            d[k] = gauss(rng);
            n += d[k] * d[k];
        }
        for (int k = 0; k < 3; ++k) d[k] /= std::sqrt(n);
    };
    for (const auto& r : ts::random_rays(box, 1500, seed)) {
        double o[3], d[3];
        for (int k = 0; k < 3; ++k) {
            o[k] = r.origin[k];
            d[k] = r.direction[k];
        }
        add(o, d, 0.0);
    }
    std::vector<std::pair<size_t, size_t>> tris;
    for (size_t cl = 0; cl < scene.triangles.size(); ++cl)
        for (size_t t = 0; t < scene.triangles[cl].size(); ++t) tris.emplace_back(cl, t);
    if (tris.empty()) return out;
    for (int i = 0; i < 1500; ++i) {
        const auto [cl, t] = tris[size_t(unit(rng) * double(tris.size())) % tris.size()];
        const ts::Triangle& tri = scene.triangles[cl][t];
        const ts::Float3& a = scene.positions[cl][tri[i % 3]];
        const ts::Float3& b = scene.positions[cl][tri[(i + 1) % 3]];
        double target[3], d[3];
        for (int k = 0; k < 3; ++k)
            target[k] = (i % 2 == 0) ? double(a[k]) : 0.5 * (double(a[k]) + double(b[k]));
        if (!std::isfinite(target[0] + target[1] + target[2])) continue;
        if (i % 5 == 4) {  // axis-parallel, at a vertex
            for (int k = 0; k < 3; ++k) {
                d[k] = 0.0;
                target[k] = a[k];
            }
            d[i % 3] = (i % 2) ? 1.0 : -1.0;
        } else {
            random_direction(d);
        }
        add(target, d, distance * (0.5 + unit(rng)));
    }
    return out;
}

std::string describe(const eng::Hit& h) {
    std::ostringstream s;
    s.precision(9);
    if (!h.hit) return "miss";
    s << "t " << h.t << " u " << h.u << " v " << h.v << " triangle " << h.triangle_index
      << " cluster " << h.cluster_id << " geometry " << h.geometry_index
      << (h.front_face ? " front" : " back");
    return s.str();
}

// Both hit at the same t (a tie at a shared vertex or edge) but name different triangles.
bool tie_only(const eng::Hit& a, const eng::Hit& b) { return a.hit && b.hit && a.t == b.t; }

bool same_hit(const eng::Hit& a, const eng::Hit& b) {
    if (a.hit != b.hit) return false;
    if (!a.hit) return true;
    return a.t == b.t && a.u == b.u && a.v == b.v && a.triangle_index == b.triangle_index &&
           a.cluster_id == b.cluster_id && a.geometry_index == b.geometry_index &&
           a.front_face == b.front_face && a.opaque == b.opaque;
}

class ClusterTraversalReference : public ::testing::TestWithParam<ReferenceCase> {};

TEST_P(ClusterTraversalReference, WalksGiveTheExhaustiveHit) {
    const ReferenceCase& c = GetParam();
    ts::TriangleMesh mesh = c.mesh();
    const auto clusters = ts::build_clusters(mesh, 64, 64);
    mesh = scaled(std::move(mesh), c.scale);
    ts::ClusterInputLayout layout;
    layout.index_bytes = 4;
    layout.truncate_bits = c.truncate_bits;
    const ts::ClusterScene scene = ts::build_cluster_scene(mesh, clusters, layout);
    ASSERT_EQ(scene.failed_builds, 0u);

    std::map<uint64_t, std::span<const std::byte>> at;
    std::vector<eng::ClusterBox> boxes;
    std::vector<eng::ClasView> views(scene.objects.size());
    for (size_t cl = 0; cl < scene.objects.size(); ++cl) {
        const auto view = eng::open_clas(scene.objects[cl]);
        ASSERT_TRUE(view) << "cluster " << cl;
        views[cl] = *view;
        const uint64_t address = (cl + 1) * kClasStride;
        at[address] = scene.objects[cl];
        eng::ClusterBox box{};
        for (int k = 0; k < 3; ++k) {
            box.bounds_min[k] = view->header.bounds_min[k];
            box.bounds_max[k] = view->header.bounds_max[k];
        }
        box.clas_address = address;
        box.reference_index = uint32_t(cl);
        box.cluster_id = view->header.cluster_id;
        boxes.push_back(box);
    }
    const std::vector<std::byte> blas = eng::build_bottom_level(boxes, uint32_t(boxes.size()));
    ASSERT_FALSE(blas.empty());
    auto clas_at = [&](uint64_t address) -> std::span<const std::byte> {
        const auto it = at.find(address);
        return it == at.end() ? std::span<const std::byte>{} : it->second;
    };

    const Rays rays = make_rays(scene, c, 7);
    ASSERT_GT(rays.rays.size(), 2000u) << scene.triangles.size() << " clusters";
    for (const eng::TraversalMode mode :
         {eng::TraversalMode::kDouble, eng::TraversalMode::kFloat32}) {
        size_t blas_bad = 0, clas_bad = 0, hits = 0, ties = 0;
        std::mt19937_64 pick(3);
        for (size_t i = 0; i < rays.rays.size(); ++i) {
            const eng::Ray& r = rays.rays[i];
            const uint32_t flags = rays.flags[i];
            const eng::BottomLevelHit walk =
                eng::trace_bottom_level_bytes(blas, clas_at, r, flags, false, mode);
            const eng::BottomLevelHit ref =
                eng::trace_bottom_level_bytes_exhaustive(blas, clas_at, r, flags, mode);
            hits += ref.hit.hit;
            // The views form (CLASes opened once) walks the same way.
            const eng::BottomLevelHit walk_views = eng::trace_bottom_level_views(
                blas,
                [&](uint64_t address) -> const eng::ClasView* {
                    return &views[address / kClasStride - 1];
                },
                r, flags, false, mode);
            if (!same_hit(walk_views.hit, walk.hit) ||
                walk_views.reference_index != walk.reference_index)
                ++blas_bad;
            if (!same_hit(walk.hit, ref.hit) ||
                (ref.hit.hit && walk.reference_index != ref.reference_index)) {
                ties += tie_only(walk.hit, ref.hit);
                if (++blas_bad <= 5)
                    ADD_FAILURE() << c.name << " " << eng::traversal_mode_name(mode) << " ray " << i
                                  << " BLAS: walk " << describe(walk.hit) << " ref "
                                  << walk.reference_index << "; exhaustive " << describe(ref.hit)
                                  << " ref " << ref.reference_index;
            }
            // One CLAS per ray: the one the exhaustive hit is in, else any.
            const size_t cl = ref.hit.hit ? ref.reference_index : pick() % views.size();
            const eng::Hit clas_walk = eng::trace_closest(views[cl], r, flags, mode);
            const eng::Hit clas_ref = eng::trace_closest_exhaustive(views[cl], r, flags, mode);
            const bool clas_same = same_hit(clas_walk, clas_ref);
            ties += !clas_same && tie_only(clas_walk, clas_ref);
            if (!clas_same && ++clas_bad <= 5)
                ADD_FAILURE() << c.name << " " << eng::traversal_mode_name(mode) << " ray " << i
                              << " CLAS " << cl << ": walk " << describe(clas_walk)
                              << "; exhaustive " << describe(clas_ref);
        }
        EXPECT_EQ(blas_bad, 0u) << c.name << " " << eng::traversal_mode_name(mode) << ": of "
                                << rays.rays.size() << " rays (BLAS and CLAS differences at the "
                                << "same t, ties: " << ties << ")";
        EXPECT_EQ(clas_bad, 0u) << c.name << " " << eng::traversal_mode_name(mode) << ": of "
                                << rays.rays.size() << " rays";
        // The rays must actually hit (a scene no ray reaches proves nothing).
        EXPECT_GT(hits, rays.rays.size() / 20) << c.name << " " << eng::traversal_mode_name(mode);
    }
}

INSTANTIATE_TEST_SUITE_P(Scenes, ClusterTraversalReference, ::testing::ValuesIn(kCases),
                         [](const auto& info) { return std::string(info.param.name); });

}  // namespace
