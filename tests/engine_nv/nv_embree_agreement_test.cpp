// SPDX-License-Identifier: Apache-2.0
// The NV engine against Embree 3 instancing: a top-level object of mirrored, scaled and
// rotated instances over triangle BLAS (several geometries, opaque and not) and an AABB
// BLAS, traced with every ray flag that changes the answer, random cull masks, and the
// instance flags (facing cull disable, flip facing, force opaque / no-opaque).
#include "nv_scene.h"

#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <random>

namespace clastrace::nvtest {
namespace {

std::vector<BlasSpec> mixed_blas() {
    std::vector<BlasSpec> out(4);
    out[0].geometries.push_back({ts::make_icosphere(3, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    out[1].geometries.push_back({ts::make_torus(24, 12, 1.0f, 0.3f), {}, 0});
    ts::TriangleMesh terrain = ts::make_terrain(12, 12, 7);
    for (auto& p : terrain.positions) p = {p[0] * 0.1f - 0.6f, p[2] * 0.1f - 0.6f, p[1] * 0.1f};
    out[1].geometries.push_back({terrain, {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    out[2].geometries.push_back(
        {ts::make_random_soup(400, 11, 1.0f, 0.4f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    out[3].aabbs = true;
    out[3].geometries.push_back({{}, random_boxes(120, 5), 0});
    out[3].geometries.push_back({{}, random_boxes(60, 6), VK_GEOMETRY_OPAQUE_BIT_NV});
    return out;
}

constexpr uint32_t kFlagSets[] = {0,
                                  eng::kRayFlagOpaque,
                                  eng::kRayFlagNoOpaque,
                                  eng::kRayFlagCullBackFacingTriangles,
                                  eng::kRayFlagCullFrontFacingTriangles,
                                  eng::kRayFlagCullOpaque,
                                  eng::kRayFlagCullNoOpaque,
                                  eng::kRayFlagCullBackFacingTriangles | eng::kRayFlagNoOpaque};

Agreement run(const std::vector<BlasSpec>& blas, const std::vector<InstanceSpec>& instances,
              size_t ray_count, float extent, uint64_t seed,
              VkBuildAccelerationStructureFlagsNV build_flags = 0) {
    auto built = build_scene(blas, instances, build_flags);
    EXPECT_TRUE(built->findings.empty()) << built->findings.front();
    std::vector<eng::Finding> findings;
    std::string error;
    auto scene = eng::NvScene::open(built->world.memory, built->tlas.address, &findings, &error);
    EXPECT_TRUE(scene) << error;
    if (!scene) return {};
    EmbreeNvScene embree(blas, instances);
    ts::Bounds box;
    box.extend({-extent, -extent, -extent});
    box.extend({extent, extent, extent});
    const auto rays = ts::random_rays(box, ray_count, seed);
    std::mt19937_64 rng(seed);
    Agreement a;
    for (size_t i = 0; i < rays.size(); ++i) {
        const eng::Ray r{{rays[i].origin[0], rays[i].origin[1], rays[i].origin[2]},
                         rays[i].tmin,
                         {rays[i].direction[0], rays[i].direction[1], rays[i].direction[2]},
                         rays[i].tmax};
        const uint32_t flags = kFlagSets[i % std::size(kFlagSets)];
        const uint32_t mask = i % 3 == 0 ? uint32_t(rng() & 0xFF) : 0xFFu;
        classify(a, scene->closest(r, flags, mask), embree.closest(r, flags, mask), 1e-5,
                 "ray " + std::to_string(i) + " flags " + std::to_string(flags) + " mask " +
                     std::to_string(mask));
        if (i % 4 == 0) {
            (scene->any(r, flags, mask) == embree.any(r, flags, mask) ? a.any_agree
                                                                      : a.any_disagree)++;
        }
    }
    return a;
}

TEST(NvEmbreeAgreement, InstancedMixedSceneWithEveryRayFlag) {
    const auto blas = mixed_blas();
    const auto instances = random_instances(48, int(blas.size()), 5.0f, 3);
    const Agreement a = run(blas, instances, 120000, 8.0f, 21);
    for (const auto& e : a.examples) ADD_FAILURE() << e;
    std::printf("[ nv-embree ] %s\n", a.summary().c_str());
    EXPECT_EQ(a.rays, 120000u);
    EXPECT_EQ(a.disagree, 0u) << a.summary();
    EXPECT_EQ(a.any_disagree, 0u) << a.summary();
    EXPECT_GT(a.agree_hit, a.rays / 5) << a.summary();  // the scene is actually hit
    EXPECT_GT(a.agree_miss, a.rays / 20) << a.summary();
    EXPECT_LT(a.tie + a.edge, a.rays / 200) << a.summary();
}

// PREFER_FAST_BUILD builds the bottom levels with the Morton builder: another tree, the
// same answers.
TEST(NvEmbreeAgreement, FastBuildMortonTreesAgree) {
    const auto blas = mixed_blas();
    const auto instances = random_instances(48, int(blas.size()), 5.0f, 3);
    const Agreement a = run(blas, instances, 40000, 8.0f, 22,
                            VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV);
    for (const auto& e : a.examples) ADD_FAILURE() << e;
    std::printf("[ nv-embree ] fast build: %s\n", a.summary().c_str());
    EXPECT_EQ(a.disagree, 0u) << a.summary();
    EXPECT_EQ(a.any_disagree, 0u) << a.summary();
    EXPECT_GT(a.agree_hit, a.rays / 5) << a.summary();
    EXPECT_LT(a.tie + a.edge, a.rays / 200) << a.summary();
}

// Dense overlapping instances of one closed mesh: most rays cross many instances and the
// closest one must win.
TEST(NvEmbreeAgreement, ManyOverlappingInstancesClosestWins) {
    std::vector<BlasSpec> blas(1);
    blas[0].geometries.push_back({ts::make_icosphere(2, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    auto instances = random_instances(300, 1, 2.0f, 9);
    const Agreement a = run(blas, instances, 40000, 3.0f, 4);
    for (const auto& e : a.examples) ADD_FAILURE() << e;
    std::printf("[ nv-embree ] %s\n", a.summary().c_str());
    EXPECT_EQ(a.disagree, 0u) << a.summary();
    EXPECT_EQ(a.any_disagree, 0u) << a.summary();
    EXPECT_GT(a.agree_hit, a.rays / 2) << a.summary();
}

}  // namespace
}  // namespace clastrace::nvtest
