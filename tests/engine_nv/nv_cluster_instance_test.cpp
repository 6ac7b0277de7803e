// SPDX-License-Identifier: Apache-2.0
// An NV top level whose instance is a cluster BLAS (NvScene opens its CLASes once and traces
// them with trace_bottom_level_views): the same hits as the cluster BLAS traversal over the
// same bytes (trace_bottom_level_bytes, each CLAS checked on every visit), in both modes,
// through an identity instance (the object ray is the world ray).
#include "nv_scene.h"

#include <clastrace/engine/blas.h>
#include <clastrace/testsupport/cluster_scene.h>
#include <clastrace/testsupport/clusters.h>
#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <map>

namespace clastrace::nvtest {
namespace {

TEST(NvClusterInstance, TopLevelOverAClusterBlasGivesTheClusterTraversalsHits) {
    const ts::TriangleMesh mesh = ts::make_icosphere(3, 1.0f);
    ts::ClusterInputLayout layout;
    layout.index_bytes = 4;
    const ts::ClusterScene clusters =
        ts::build_cluster_scene(mesh, ts::build_clusters(mesh, 64, 64), layout);
    ASSERT_EQ(clusters.failed_builds, 0u);

    NvWorld w;
    std::map<uint64_t, std::span<const std::byte>> at;
    std::vector<eng::ClusterBox> boxes;
    for (size_t cl = 0; cl < clusters.objects.size(); ++cl) {
        const auto& object = clusters.objects[cl];
        const auto view = eng::open_clas(object);
        ASSERT_TRUE(view) << "cluster " << cl;
        eng::ClusterBox box{};
        for (int k = 0; k < 3; ++k) {
            box.bounds_min[k] = view->header.bounds_min[k];
            box.bounds_max[k] = view->header.bounds_max[k];
        }
        box.clas_address = w.put(object.data(), object.size(), "clas");
        box.reference_index = uint32_t(cl);
        box.cluster_id = view->header.cluster_id;
        at[box.clas_address] = object;
        boxes.push_back(box);
    }
    const std::vector<std::byte> blas = eng::build_bottom_level(boxes, uint32_t(boxes.size()));
    ASSERT_FALSE(blas.empty());
    const uint64_t blas_address = w.put(blas.data(), blas.size(), "cluster blas");

    eng::NvObjectInfo top;
    top.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    top.instance_count = 1;
    const std::vector<uint8_t> instances = w.instance_bytes({InstanceSpec{}}, {blas_address});
    const uint64_t instance_address = w.put(instances.data(), instances.size(), "instances");
    eng::NvObjectBinding tlas = w.make_object(top, "tlas");
    const eng::ExecutionRecord built = w.build(top, tlas, instance_address);
    ASSERT_TRUE(built.ops[0].executed);
    std::vector<eng::Finding> findings;
    std::string error;
    const auto scene = eng::NvScene::open(w.memory, tlas.address, &findings, &error);
    ASSERT_TRUE(scene) << error;
    EXPECT_EQ(scene->instances_reached(), 1u);
    EXPECT_TRUE(findings.empty());

    auto clas_at = [&](uint64_t address) -> std::span<const std::byte> {
        const auto it = at.find(address);
        return it == at.end() ? std::span<const std::byte>{} : it->second;
    };
    for (const eng::TraversalMode mode :
         {eng::TraversalMode::kDouble, eng::TraversalMode::kFloat32}) {
        size_t hits = 0, differ = 0;
        for (const auto& t : ts::random_rays(ts::bounds_of(mesh), 3000, 11)) {
            const eng::Ray ray{{t.origin[0], t.origin[1], t.origin[2]},
                               0.0f,
                               {t.direction[0], t.direction[1], t.direction[2]},
                               t.tmax};
            const eng::NvHit got = scene->closest(ray, 0, 0xFF, mode);
            const eng::BottomLevelHit want =
                eng::trace_bottom_level_bytes(blas, clas_at, ray, 0, false, mode);
            hits += want.hit.hit;
            const bool same =
                got.hit == want.hit.hit &&
                (!got.hit || (got.t == want.hit.t && got.u == want.hit.u && got.v == want.hit.v &&
                              got.primitive_index == want.hit.triangle_index &&
                              got.cluster_id == want.hit.cluster_id));
            if (!same && ++differ <= 5)
                ADD_FAILURE() << eng::traversal_mode_name(mode) << ": top level "
                              << (got.hit ? got.t : -1.0f) << ", cluster BLAS "
                              << (want.hit.hit ? want.hit.t : -1.0f);
        }
        EXPECT_EQ(differ, 0u);
        EXPECT_GT(hits, 1000u);
    }
}

}  // namespace
}  // namespace clastrace::nvtest
