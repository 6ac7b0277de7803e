// SPDX-License-Identifier: Apache-2.0
// The NV engine against Embree 3 instancing: a top-level object of mirrored, scaled and
// rotated instances over triangle BLAS (several geometries, opaque and not) and an AABB
// BLAS, traced with every ray flag that changes the answer, random cull masks, and the
// instance flags (facing cull disable, flip facing, force opaque / no-opaque).
#include "nv_scene.h"

#include <gtest/gtest.h>


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
    return compare_with_embree(*scene, EmbreeNvScene(blas, instances), ray_count, extent, seed);
}

TEST(NvEmbreeAgreement, InstancedMixedSceneWithEveryRayFlag) {
    const auto blas = mixed_blas();
    const auto instances = random_instances(48, int(blas.size()), 5.0f, 3);
    const Agreement a = run(blas, instances, 120000, 8.0f, 21);
    EXPECT_EQ(a.rays, 120000u);
    expect_agreement(a, "nv instanced mixed scene");
}

// PREFER_FAST_BUILD builds the bottom levels with the Morton builder: another tree, the
// same answers.
TEST(NvEmbreeAgreement, FastBuildMortonTreesAgree) {
    const auto blas = mixed_blas();
    const auto instances = random_instances(48, int(blas.size()), 5.0f, 3);
    const Agreement a = run(blas, instances, 40000, 8.0f, 22,
                            VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV);
    expect_agreement(a, "nv fast build", {.hit_divisor = 5, .miss_divisor = 0});
}

// Dense overlapping instances of one closed mesh: most rays cross many instances and the
// closest one must win.
TEST(NvEmbreeAgreement, ManyOverlappingInstancesClosestWins) {
    std::vector<BlasSpec> blas(1);
    blas[0].geometries.push_back({ts::make_icosphere(2, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    auto instances = random_instances(300, 1, 2.0f, 9);
    const Agreement a = run(blas, instances, 40000, 3.0f, 4);
    expect_agreement(a, "nv overlapping instances", {.hit_divisor = 2, .miss_divisor = 0});
}

}  // namespace
}  // namespace clastrace::nvtest
