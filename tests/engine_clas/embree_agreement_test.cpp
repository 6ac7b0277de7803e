// SPDX-License-Identifier: Apache-2.0
// Every ray agrees with Embree 3 (robust mode, same truncated float positions) on hit/miss,
// on t (relative 1e-6) and on the primitive, except where Embree itself reports a tie.
// Each scene gets >= 10^6 rays: a 724x724 pinhole camera grid plus 2^19 random rays.
#include "clastrace/engine/traversal.h"
#include "clastrace/testsupport/cluster_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <iostream>

namespace ts = clastrace::testsupport;

namespace {

struct AgreementCase {
    std::string label;
    std::function<ts::TriangleMesh()> mesh;
    size_t max_vertices, max_triangles;
    ts::ClusterInputLayout layout;
};

std::ostream& operator<<(std::ostream& os, const AgreementCase& c) { return os << c.label; }

ts::TriangleMesh assimp(const char* rel) { return ts::load_mesh(ts::assimp_models_dir() / rel); }

void run_agreement(const AgreementCase& c, const std::vector<ts::TestRay>& rays,
                   const char* ray_kind, const ts::ClusterScene& scene,
                   const ts::EmbreeReference& embree) {
    const ts::AgreementCounts counts = ts::compare_with_embree(scene, embree, rays, 1e-6);
    std::cout << "[agreement] " << c.label << " " << ray_kind << ": " << counts.summary() << "\n";
    for (const auto& e : counts.examples) std::cout << "    " << e << "\n";
    // Two of the t kind, and every hit/miss and prim kind (rare: a few per million rays).
    size_t t_shown = 0;
    for (const auto& e : counts.embree_off_examples)
        if (e[0] != 't' || t_shown++ < 2) std::cout << "    embree-off " << e << "\n";
    EXPECT_EQ(counts.rays, rays.size());
    EXPECT_EQ(counts.disagreements(), 0u) << c.label << " " << ray_kind << ": " << counts.summary();
    // The ray set must exercise the scene, or agreement proves nothing.
    EXPECT_GT(counts.agree_hit, rays.size() / 20) << c.label << " " << ray_kind;
    EXPECT_GT(counts.agree_miss + counts.agree_hit + counts.tie, 0u);
}

class EmbreeAgreement : public ::testing::TestWithParam<AgreementCase> {};

TEST_P(EmbreeAgreement, ClosestHitMatchesOnMillionRays) {
    const AgreementCase& c = GetParam();
    ts::TriangleMesh mesh;
    try {
        mesh = c.mesh();
    } catch (const ts::MeshLoadError& e) {
        if (!std::filesystem::exists(ts::assimp_models_dir()))
            GTEST_SKIP() << "assimp-testmodels not installed";
        throw;
    }
    const auto clusters = ts::build_clusters(mesh, c.max_vertices, c.max_triangles);
    const ts::ClusterScene scene = ts::build_cluster_scene(mesh, clusters, c.layout);
    ASSERT_EQ(scene.failed_builds, 0u);
    for (size_t i = 0; i < scene.findings.size(); ++i)
        for (const auto& f : scene.findings[i])
            ADD_FAILURE() << "cluster " << i << ": " << f.rule << ": " << f.message;

    ts::EmbreeReference embree(/*robust=*/true);
    ts::add_to_embree(scene, embree);

    ts::Bounds box;
    for (const ts::Bounds& b : scene.bounds) {
        box.extend(b.lo);
        box.extend(b.hi);
    }
    std::cout << "[agreement] " << c.label << ": " << mesh.triangles.size() << " triangles in "
              << clusters.size() << " clusters, truncate " << c.layout.truncate_bits
              << " bits, index " << c.layout.index_bytes << " B stride " << c.layout.index_stride
              << ", vertex stride " << c.layout.vertex_stride << "\n";
    run_agreement(c, ts::camera_rays(box, 724, 724, 11), "coherent", scene, embree);
    run_agreement(c, ts::random_rays(box, size_t(1) << 19, 12), "random", scene, embree);
}

const AgreementCase kCases[] = {
    {"WusonOBJ_idx8", [] { return assimp("OBJ/WusonOBJ.obj"); }, 64, 124, {1, 0, 0, 0}},
    {"spider_idx16_strided_trunc8",
     [] { return assimp("OBJ/spider.obj"); },
     64,
     124,
     {2, 4, 16, 8}},
    {"WusonPLY_idx32_trunc12", [] { return assimp("PLY/Wuson.ply"); }, 128, 128, {4, 0, 20, 12}},
    {"icosphere5_255v256t", [] { return ts::make_icosphere(5, 1.0f); }, 255, 256, {1, 0, 0, 0}},
    {"torus_trunc16", [] { return ts::make_torus(96, 48, 1.0f, 0.35f); }, 64, 124, {2, 0, 0, 16}},
    {"terrain_idx16_stride6", [] { return ts::make_terrain(100, 100, 5); }, 128, 128, {2, 6, 0, 0}},
    {"soup20k",
     [] { return ts::make_random_soup(20000, 21, 10.0f, 1.5f); },
     128,
     128,
     {1, 0, 0, 0}},
    {"soup20k_trunc4_idx32",
     [] { return ts::make_random_soup(20000, 22, 10.0f, 1.5f); },
     128,
     128,
     {4, 8, 16, 4}},
};

INSTANTIATE_TEST_SUITE_P(Scenes, EmbreeAgreement, ::testing::ValuesIn(kCases),
                         [](const ::testing::TestParamInfo<AgreementCase>& info) {
                             return info.param.label;
                         });

// Any-hit queries (rtcOccluded1 vs trace_any over the clusters) on segments that end inside
// the scene, so that both answers occur. A segment ending within 1e-6 of the closest t is a
// boundary case that neither side owes the other; it is counted, not compared.
TEST(EmbreeAgreementAnyHit, OcclusionMatchesOnSegments) {
    for (const ts::TriangleMesh& mesh :
         {ts::make_icosphere(4, 2.0f), ts::make_random_soup(10000, 5, 5.0f, 1.0f)}) {
        const auto clusters = ts::build_clusters(mesh, 64, 124);
        const ts::ClusterScene scene = ts::build_cluster_scene(mesh, clusters, {});
        ts::EmbreeReference embree(true);
        ts::add_to_embree(scene, embree);
        auto rays = ts::random_rays(ts::bounds_of(mesh), 200000, 77);
        const float reach =
            0.75f * ts::bounds_of(mesh).diagonal();  // origin sits this far from the centre
        size_t occluded = 0, clear = 0, boundary = 0, mismatches = 0;
        for (size_t i = 0; i < rays.size(); ++i) {
            ts::TestRay r = rays[i];
            r.tmax = reach * (0.5f + float(i % 97) / 97.0f);
            const bool engine_any = ts::trace_scene_any(scene, r);
            const bool embree_any = embree.occluded(r);
            const ts::ReferenceHit closest =
                embree.intersect(ts::TestRay{r.origin, r.tmin, r.direction, 3.4e38f});
            if (closest.hit && std::fabs(closest.t - r.tmax) <= 1e-6f * r.tmax) {
                ++boundary;
                continue;
            }
            if (engine_any != embree_any) ++mismatches;
            (embree_any ? occluded : clear) += 1;
        }
        std::cout << "[any-hit] " << mesh.name << ": occluded " << occluded << ", clear " << clear
                  << ", boundary " << boundary << ", mismatches " << mismatches << "\n";
        EXPECT_EQ(mismatches, 0u) << mesh.name;
        EXPECT_GT(occluded, rays.size() / 20);
        EXPECT_GT(clear, rays.size() / 20);
    }
}

}  // namespace
