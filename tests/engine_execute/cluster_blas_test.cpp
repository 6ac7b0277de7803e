// SPDX-License-Identifier: Apache-2.0
// Bottom-level builds traced against Embree, instantiated clusters, determinism.
#include "embree_scene.h"
#include "execute_rig.h"

#include <tbb/task_arena.h>

#include <cstdio>

namespace clastrace::engine::execute_test {
namespace {

TEST(ClusterBlas, TracesLikeEmbreeOverTheSameTriangles) {
    Rig rig(16);
    ClusteredMesh m = icosphere_meshlets(5);  // 20480 triangles
    ASSERT_GT(m.clusters.size(), 100u);
    auto clas = build_clas(rig, m);
    uint64_t blas = build_blas(rig, clas);
    auto check = read_bottom_level_header(rig.bytes(blas, rig.get<uint32_t>(blas + 8)));
    ASSERT_TRUE(check.header) << check.error;
    EXPECT_EQ(check.header->reference_count, m.clusters.size());
    EXPECT_EQ(blas % EngineProperties{}.cluster_bottom_level_byte_alignment, 0u);
    expect_matches_embree(rig, blas, m);
}

TEST(ClusterBlas, HitReportsTheReferenceIndexAndAddress) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(3);
    auto clas = build_clas(rig, m);
    std::vector<uint64_t> reversed(clas.rbegin(), clas.rend());
    uint64_t blas = build_blas(rig, reversed);
    Ray r{{0, 0, 3}, 0.0f, {0, 0, -1}, 100.0f};
    BottomLevelHit h = trace_bottom_level_closest(rig.memory, blas, r, 0);
    ASSERT_TRUE(h.hit.hit);
    EXPECT_NEAR(h.hit.t, 2.0f, 0.02f);
    EXPECT_EQ(h.clas_address, reversed[h.reference_index]);
    EXPECT_EQ(h.clas_address, clas[h.hit.cluster_id]);
    EXPECT_TRUE(trace_bottom_level_any(rig.memory, blas, r, 0));
    Ray away{{0, 0, 3}, 0.0f, {0, 0, 1}, 100.0f};
    EXPECT_FALSE(trace_bottom_level_closest(rig.memory, blas, away, 0).hit.hit);
    EXPECT_FALSE(trace_bottom_level_any(rig.memory, blas, away, 0));
}

TEST(ClusterBlas, InstantiatedClustersTraceLikeEmbree) {
    Rig rig(16);
    ClusteredMesh m = icosphere_meshlets(4);
    const uint32_t n = uint32_t(m.clusters.size());
    uint64_t tinfos = upload_cluster_infos(rig, m, /*as_templates=*/true);
    CommandSetup ts;
    setup_command(ts, rig,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, n, tinfos);
    ExecutionRecord tr = execute(ts.cmd, rig.memory);
    ASSERT_TRUE(tr.findings.empty()) << describe(tr.findings);
    claim_implicit(rig, tr);
    auto templates = dst_addresses(rig, ts.cmd, n);
    std::vector<VkClusterAccelerationStructureInstantiateClusterInfoNV> inst(n);
    for (uint32_t c = 0; c < n; ++c) {
        inst[c].clusterIdOffset = 1000;
        inst[c].clusterTemplateAddress = templates[c];
        inst[c].vertexBuffer = {rig.put_vec(rig.inputs, m.clusters[c].positions, 16), 12};
    }
    CommandSetup is;
    setup_command(is, rig,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, n,
                  rig.put_vec(rig.inputs, inst, 16));
    ExecutionRecord ir = execute(is.cmd, rig.memory);
    ASSERT_TRUE(ir.findings.empty()) << describe(ir.findings);
    claim_implicit(rig, ir);
    auto clas = dst_addresses(rig, is.cmd, n);
    // The instantiation read each template as an acceleration structure.
    size_t template_reads = 0;
    for (const auto& a : ir.accesses)
        template_reads +=
            a.access == VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR && !a.is_write;
    EXPECT_EQ(template_reads, n);
    uint64_t blas = build_blas(rig, clas);
    expect_matches_embree(rig, blas, m, /*id_base=*/1000);
}

// Everything a build writes, byte for byte, on 1 and 2 threads.
std::map<uint64_t, std::vector<std::byte>> build_scene_bytes(int threads,
                                                             ExecutionRecord* blas_record) {
    tbb::task_arena arena(threads);
    std::map<uint64_t, std::vector<std::byte>> out;
    arena.execute([&] {
        Rig rig(16);
        ClusteredMesh m = icosphere_meshlets(5);
        auto clas = build_clas(rig, m);
        // Several BLAS in one command: over all clusters, the first half, every third.
        std::vector<std::vector<uint64_t>> sets(3);
        for (size_t i = 0; i < clas.size(); ++i) {
            sets[0].push_back(clas[i]);
            if (i < clas.size() / 2) sets[1].push_back(clas[i]);
            if (i % 3 == 0) sets[2].push_back(clas[i]);
        }
        std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> infos;
        for (auto& s : sets) {
            uint64_t info = upload_blas_info(rig, s);
            infos.push_back(
                rig.get<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV>(info));
        }
        CommandSetup s;
        setup_command(s, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, 3,
                      rig.put_vec(rig.inputs, infos, 16));
        *blas_record = execute(s.cmd, rig.memory);
        out = rig.snapshot();
    });
    return out;
}

TEST(ClusterBlas, SameBytesOnOneAndTwoThreads) {
    ExecutionRecord r1, r2;
    auto one = build_scene_bytes(1, &r1);
    auto two = build_scene_bytes(2, &r2);
    ASSERT_TRUE(r1.findings.empty()) << describe(r1.findings);
    ASSERT_EQ(one.size(), two.size());
    for (const auto& [base, bytes] : one)
        EXPECT_TRUE(bytes == two.at(base)) << "region " << std::hex << base;
    ASSERT_EQ(r1.accesses.size(), r2.accesses.size());
    for (size_t i = 0; i < r1.accesses.size(); ++i) {
        EXPECT_EQ(r1.accesses[i].begin, r2.accesses[i].begin);
        EXPECT_EQ(r1.accesses[i].end, r2.accesses[i].end);
        EXPECT_EQ(r1.accesses[i].field, r2.accesses[i].field);
    }
    EXPECT_EQ(r1.implicit_bytes_used, r2.implicit_bytes_used);
}

// ExecuteOptions::implicit_object_room (traceable cluster BLASes): each implicit object takes
// the room, so the next one starts a room later, dstSizesArray says the room, and each object's
// own bytes are the ones packed without it.
TEST(ClusterBlas, ImplicitObjectRoomSpacesTheObjectsApart) {
    Rig rig(16);
    ClusteredMesh m = icosphere_meshlets(3);
    auto clas = build_clas(rig, m);
    const std::vector<uint64_t> half(clas.begin(), clas.begin() + clas.size() / 2);
    std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> infos;
    const std::vector<uint64_t>* sets[] = {&clas, &half, &clas};
    for (const std::vector<uint64_t>* set : sets)
        infos.push_back(rig.get<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV>(
            upload_blas_info(rig, *set)));
    const uint64_t src = rig.put_vec(rig.inputs, infos, 16);
    auto run = [&](uint64_t room, std::vector<uint64_t>& at, std::vector<uint32_t>& sizes) {
        CommandSetup s;
        setup_command(s, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, 3, src);
        ExecuteOptions options;
        options.implicit_object_room = room;
        const ExecutionRecord r = execute(s.cmd, rig.memory, options);
        EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
        claim_implicit(rig, r);
        at = dst_addresses(rig, s.cmd, 3);
        for (uint32_t i = 0; i < 3; ++i)
            sizes.push_back(rig.get<uint32_t>(s.cmd.dstSizesArray.deviceAddress + 4ull * i));
        return r.implicit_bytes_used;
    };
    std::vector<uint64_t> packed, roomy;
    std::vector<uint32_t> packed_sizes, roomy_sizes;
    run(0, packed, packed_sizes);
    constexpr uint64_t kRoom = 64 << 10;  // more than any of the three objects
    for (uint32_t size : packed_sizes) ASSERT_LT(size, kRoom);
    EXPECT_EQ(run(kRoom, roomy, roomy_sizes), 3 * kRoom);  // the last object takes its room too
    EXPECT_EQ(roomy[1], roomy[0] + kRoom);
    EXPECT_EQ(roomy[2], roomy[0] + 2 * kRoom);
    EXPECT_EQ(roomy_sizes, (std::vector<uint32_t>(3, uint32_t(kRoom))));
    for (uint32_t i = 0; i < 3; ++i) {
        // The same object, but for the addresses of the clusters it names (the same CLAS).
        SCOPED_TRACE("op " + std::to_string(i));
        EXPECT_TRUE(rig.bytes(packed[i], packed_sizes[i]) == rig.bytes(roomy[i], packed_sizes[i]));
    }
    // Without a room the objects are packed by their own sizes, as before.
    EXPECT_EQ(packed[1], packed[0] + (packed_sizes[0] + 255) / 256 * 256);
}

TEST(ClusterBlas, LargeBuildIsParallelAndStillDeterministic) {
    // 60000 boxes: the top of the tree builds its halves on different threads.
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(0.0f, 1000.0f);
    std::vector<ClusterBox> boxes(60000);
    for (uint32_t i = 0; i < boxes.size(); ++i) {
        float x = u(rng), y = u(rng), z = u(rng);
        boxes[i] = {{x, y, z}, {x + 1 + u(rng) * 0.01f, y + 1, z + 1}, 0x10000ull * (i + 1), i, i};
    }
    std::vector<std::byte> one, two;
    tbb::task_arena(1).execute([&] { one = build_bottom_level(boxes, uint32_t(boxes.size())); });
    tbb::task_arena(2).execute([&] { two = build_bottom_level(boxes, uint32_t(boxes.size())); });
    ASSERT_EQ(one, two);
    auto h = read_bottom_level_header(one);
    ASSERT_TRUE(h.header) << h.error;
    // Every reference appears exactly once, every node box contains its children's.
    std::vector<int> seen(boxes.size());
    std::vector<BottomLevelNode> nodes(h.header->node_count);
    std::memcpy(nodes.data(), one.data() + h.header->nodes_offset,
                nodes.size() * sizeof(BottomLevelNode));
    for (const auto& n : nodes) {
        if (n.count == 0) {
            for (uint32_t c : {n.first, n.first + 1})
                for (int a = 0; a < 3; ++a) {
                    EXPECT_LE(n.bounds_min[a], nodes[c].bounds_min[a]);
                    EXPECT_GE(n.bounds_max[a], nodes[c].bounds_max[a]);
                }
            continue;
        }
        for (uint32_t k = 0; k < n.count; ++k) {
            ClusterReference r;
            std::memcpy(&r, one.data() + h.header->references_offset + sizeof r * (n.first + k),
                        sizeof r);
            ++seen[r.reference_index];
            for (int a = 0; a < 3; ++a) {
                EXPECT_LE(n.bounds_min[a], boxes[r.reference_index].bounds_min[a]);
                EXPECT_GE(n.bounds_max[a], boxes[r.reference_index].bounds_max[a]);
            }
        }
    }
    for (int s : seen) ASSERT_EQ(s, 1);
}

TEST(ClusterBlas, EmptyAndDegenerateInputs) {
    // No references: a valid empty BLAS that never hits.
    Rig rig;
    uint64_t blas = build_blas(rig, {});
    auto check = read_bottom_level_header(rig.bytes(blas, sizeof(BottomLevelHeader)));
    ASSERT_TRUE(check.header) << check.error;
    EXPECT_EQ(check.header->node_count, 0u);
    Ray r{{0, 0, 3}, 0.0f, {0, 0, -1}, 100.0f};
    EXPECT_FALSE(trace_bottom_level_closest(rig.memory, blas, r, 0).hit.hit);
    // Boxes that all coincide, and a huge-but-finite one: still a valid tree.
    std::vector<ClusterBox> boxes(100);
    for (uint32_t i = 0; i < boxes.size(); ++i) {
        boxes[i] = {{0, 0, 0}, {1, 1, 1}, 0x1000ull * i, i, i};
    }
    boxes[5] = {{-3e38f, -3e38f, -3e38f}, {3e38f, 3e38f, 3e38f}, 0x9999, 5, 5};
    boxes[6] = {{1, 1, 1}, {0, 0, 0}, 0x8888, 6, 6};  // empty: left out
    auto bytes = build_bottom_level(boxes, 100);
    auto h = read_bottom_level_header(bytes);
    ASSERT_TRUE(h.header) << h.error;
    EXPECT_EQ(h.header->reference_count, 99u);
    EXPECT_EQ(h.header->input_reference_count, 100u);
    EXPECT_LE(bytes.size(), bottom_level_size_bound(100));
}

TEST(ClusterBlas, DenormalCentroidExtentsBuildAValidTree) {
    // Centroids 1e-44 apart on x (a denormal extent: 16 / extent overflows to infinity) and
    // 1e-38 apart on y: a fuzzed trace's boxes once indexed a bin far outside the array here.
    std::vector<ClusterBox> boxes;
    for (uint32_t i = 0; i < 60; ++i) {
        const float x = (i % 2) ? 1e-44f : 0.0f, y = (i % 3) ? 1e-38f : 0.0f;
        boxes.push_back({{x, y, float(i % 5)}, {x, y, float(i % 5)}, 0x1000ull * (i + 1), i, i});
    }
    auto bytes = build_bottom_level(boxes, uint32_t(boxes.size()));
    auto h = read_bottom_level_header(bytes);
    ASSERT_TRUE(h.header) << h.error;
    EXPECT_EQ(h.header->reference_count, boxes.size());
    std::vector<int> seen(boxes.size());
    for (uint32_t k = 0; k < h.header->reference_count; ++k) {
        ClusterReference r;
        std::memcpy(&r, bytes.data() + h.header->references_offset + sizeof r * k, sizeof r);
        ASSERT_LT(r.reference_index, boxes.size());
        ++seen[r.reference_index];
    }
    for (int s : seen) EXPECT_EQ(s, 1);
}

TEST(ClusterBlas, CorruptBottomLevelBytesAreRejected) {
    std::vector<ClusterBox> boxes;
    for (uint32_t i = 0; i < 50; ++i)
        boxes.push_back({{float(i), 0, 0}, {float(i) + 1, 1, 1}, 0x1000ull * i, i, i});
    auto good = build_bottom_level(boxes, 50);
    ASSERT_TRUE(read_bottom_level_header(good).header);
    std::mt19937 rng(3);
    size_t rejected = 0;
    for (int trial = 0; trial < 2000; ++trial) {
        auto bad = good;
        // Flip bytes in the header and node area: child indices and counts.
        for (int k = 0; k < 4; ++k)
            bad[rng() % std::min<size_t>(bad.size(), 64 + 32 * 20)] ^= std::byte(1u << (rng() % 8));
        auto check = read_bottom_level_header(bad);
        rejected += !check.header;
        if (check
                .header) {  // accepted bytes must be safe to walk: children after parents, in range
            for (uint32_t i = 0; i < check.header->node_count; ++i) {
                BottomLevelNode n;
                std::memcpy(&n, bad.data() + check.header->nodes_offset + 32ull * i, 32);
                if (n.count == 0) {
                    ASSERT_GT(n.first, i);
                    ASSERT_LT(n.first + 1, check.header->node_count);
                } else {
                    ASSERT_LE(n.first + n.count, check.header->reference_count);
                }
            }
        }
    }
    EXPECT_GT(rejected, 0u);
}

}  // namespace
}  // namespace clastrace::engine::execute_test
