// SPDX-License-Identifier: Apache-2.0
// Property: for random inputs within the limits, every actual size <= the build-sizes bound.
#include "execute_rig.h"

#include <cstdio>

namespace clastrace::engine::execute_test {
namespace {

struct Slack {
    const char* what;
    double min_ratio = 1e9, sum_ratio = 0;
    size_t n = 0;
    void add(uint64_t actual, uint64_t bound) {
        double r = bound ? double(actual) / double(bound) : 1.0;
        min_ratio = std::min(min_ratio, r);
        sum_ratio += r;
        ++n;
    }
    ~Slack() {
        if (n)
            std::printf("  %-34s actual/bound: min %.3f, mean %.3f over %zu\n", what, min_ratio,
                        sum_ratio / double(n), n);
    }
};

// Random clusters within `in`'s limits.
struct RandomClusters {
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV> infos;
    std::vector<std::vector<float>> positions;
    uint64_t triangles = 0, vertices = 0;
};

RandomClusters random_clusters(Rig& rig, std::mt19937& rng,
                               const VkClusterAccelerationStructureTriangleClusterInputNV& in,
                               uint32_t count, bool templates) {
    RandomClusters rc;
    std::uniform_real_distribution<float> pos(-100.0f, 100.0f);
    for (uint32_t c = 0; c < count; ++c) {
        uint32_t v = 3 + rng() % (in.maxClusterVertexCount - 2);
        uint32_t t = 1 + rng() % in.maxClusterTriangleCount;
        std::vector<float> p(3 * v);
        for (float& x : p) x = pos(rng);
        uint32_t index_bytes = 1u << (rng() % 3);
        if (v > 256 && index_bytes == 1) index_bytes = 2;
        std::vector<uint8_t> idx(3ull * t * index_bytes);
        for (uint32_t k = 0; k < 3 * t; ++k) {
            uint32_t value = rng() % v;
            std::memcpy(idx.data() + k * index_bytes, &value, index_bytes);
        }
        VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV info{};
        info.clusterID = c;
        info.triangleCount = t;
        info.vertexCount = v;
        info.positionTruncateBitCount = in.minPositionTruncateBitCount + rng() % 4;
        info.indexType = index_bytes;  // 1, 2, 4 are the 8/16/32-bit flag values
        info.baseGeometryIndexAndGeometryFlags.geometryIndex =
            rng() % (in.maxGeometryIndexValue + 1);
        info.baseGeometryIndexAndGeometryFlags.geometryFlags = rng() % 8;
        info.indexBufferStride = uint16_t(index_bytes);
        info.vertexBufferStride = 12;
        info.indexBuffer = rig.put_vec(rig.inputs, idx, 16);
        info.vertexBuffer = rig.put_vec(rig.inputs, p, 16);
        if (templates && rng() % 2) {
            float box[6] = {-200, -200, -200, 200, 200, 200};
            info.instantiationBoundingBoxLimit = rig.put(rig.inputs, box, sizeof box, 32);
        }
        rc.infos.push_back(info);
        rc.positions.push_back(std::move(p));
        rc.triangles += t;
        rc.vertices += v;
    }
    return rc;
}

uint64_t put_infos(Rig& rig, const RandomClusters& rc, bool templates) {
    std::vector<std::byte> bytes;
    size_t size = templates
                      ? sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV)
                      : sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    for (const auto& i : rc.infos) {
        const std::byte* p = reinterpret_cast<const std::byte*>(&i);
        bytes.insert(bytes.end(), p, p + size);
    }
    return rig.put_vec(rig.inputs, bytes, 16);
}

// Runs the command implicitly and checks every size against the bounds.
ExecutionRecord run_and_check(Rig& rig, CommandSetup& s, ObjectDirectory& dir, Slack& object_slack,
                              Slack& total_slack) {
    ExecuteOptions o;
    o.directory = &dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
    claim_implicit(rig, r);
    BuildSizes implicit = cluster_build_sizes(s.cmd.input, EngineProperties{});
    auto ex = s.cmd.input;
    ex.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    BuildSizes explicit_sizes = cluster_build_sizes(ex, EngineProperties{});
    EXPECT_TRUE(implicit.findings.empty());
    EXPECT_EQ(explicit_sizes.acceleration_structure_size, implicit.single_object_size);
    for (const OpResult& op : r.ops) {
        EXPECT_TRUE(op.executed);
        EXPECT_LE(op.dst_size, explicit_sizes.acceleration_structure_size);
        object_slack.add(op.dst_size, explicit_sizes.acceleration_structure_size);
    }
    EXPECT_LE(r.implicit_bytes_used, implicit.acceleration_structure_size);
    EXPECT_LE(r.scratch_bytes_used, implicit.build_scratch_size);
    EXPECT_EQ(implicit.build_scratch_size, explicit_sizes.build_scratch_size);
    total_slack.add(r.implicit_bytes_used, implicit.acceleration_structure_size);
    // Compute-sizes mode needs no object memory.
    auto cs = s.cmd.input;
    cs.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
    EXPECT_EQ(cluster_build_sizes(cs, EngineProperties{}).acceleration_structure_size, 0u);
    return r;
}

TEST(BuildSizes, RandomInputsStayWithinTheBounds) {
    std::mt19937 rng(2024);
    Slack clas{"CLAS object"}, clas_total{"CLAS implicit total"}, tmpl{"template object"},
        tmpl_total{"template implicit total"}, inst{"instantiated CLAS object"},
        inst_total{"instantiated implicit total"}, idx{"template indices"},
        idx_total{"template indices total"}, blas{"BLAS object"}, blas_total{"BLAS implicit total"},
        mv{"moved object"}, mv_total{"move implicit total"};
    for (int trial = 0; trial < 24; ++trial) {
        Rig rig(8);
        ObjectDirectory dir;
        VkClusterAccelerationStructureTriangleClusterInputNV in = triangle_input();
        in.maxClusterTriangleCount = 1 + rng() % 256;
        in.maxClusterVertexCount = 3 + rng() % 254;
        in.maxGeometryIndexValue = rng() % 1000;
        in.minPositionTruncateBitCount = rng() % 8;
        const uint32_t count = 1 + rng() % 24;
        // Clusters.
        RandomClusters rc = random_clusters(rig, rng, in, count, false);
        in.maxTotalTriangleCount = uint32_t(rc.triangles);
        in.maxTotalVertexCount = uint32_t(rc.vertices);
        CommandSetup s;
        setup_command(s, rig, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, count,
                      put_infos(rig, rc, false));
        s.triangles = in;
        ExecutionRecord cr = run_and_check(rig, s, dir, clas, clas_total);
        std::vector<uint64_t> clas_addresses = dst_addresses(rig, s.cmd, count);
        // Templates, their instances and their indices.
        RandomClusters rt = random_clusters(rig, rng, in, count, true);
        in.maxTotalTriangleCount = uint32_t(std::max(rc.triangles, rt.triangles));
        in.maxTotalVertexCount = uint32_t(std::max(rc.vertices, rt.vertices));
        CommandSetup ts;
        setup_command(ts, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, count,
                      put_infos(rig, rt, true));
        ts.triangles = in;
        run_and_check(rig, ts, dir, tmpl, tmpl_total);
        auto templates = dst_addresses(rig, ts.cmd, count);
        std::vector<VkClusterAccelerationStructureInstantiateClusterInfoNV> ii(count);
        for (uint32_t c = 0; c < count; ++c) {
            ii[c].clusterTemplateAddress = templates[c];
            ii[c].vertexBuffer = {rig.put_vec(rig.inputs, rt.positions[c], 16), 12};
        }
        CommandSetup is;
        setup_command(is, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, count,
                      rig.put_vec(rig.inputs, ii, 16));
        is.triangles = in;
        run_and_check(rig, is, dir, inst, inst_total);
        CommandSetup gs;
        setup_command(gs, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, count,
                      rig.put_vec(rig.inputs, templates, 16));
        gs.triangles = in;
        run_and_check(rig, gs, dir, idx, idx_total);
        // BLAS over random subsets of the CLAS.
        const uint32_t blas_count = 1 + rng() % 4;
        std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> bi;
        uint32_t total = 0, per = 0;
        for (uint32_t b = 0; b < blas_count; ++b) {
            std::vector<uint64_t> refs;
            for (uint64_t a : clas_addresses)
                if (rng() % 2) refs.push_back(a);
            total += uint32_t(refs.size());
            per = std::max(per, uint32_t(refs.size()));
            bi.push_back(rig.get<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV>(
                upload_blas_info(rig, refs)));
        }
        CommandSetup bs;
        setup_command(bs, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV,
                      blas_count, rig.put_vec(rig.inputs, bi, 16));
        bs.bottom.maxTotalClusterCount = total;
        bs.bottom.maxClusterCountPerAccelerationStructure = per;
        run_and_check(rig, bs, dir, blas, blas_total);
        // Move the CLAS; maxMovedBytes is what they add up to.
        uint64_t moved = 0;
        for (const OpResult& op : cr.ops) moved += op.dst_size;
        CommandSetup ms;
        setup_command(ms, rig, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, count,
                      rig.put_vec(rig.inputs, clas_addresses, 16));
        ms.move.maxMovedBytes = moved;
        run_and_check(rig, ms, dir, mv, mv_total);
    }
}

TEST(BuildSizes, ModesAndBadInputs) {
    EngineProperties p;
    VkClusterAccelerationStructureTriangleClusterInputNV tri = triangle_input();
    VkClusterAccelerationStructureInputInfoNV info{};
    info.maxAccelerationStructureCount = 10;
    info.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    info.opInput.pTriangleClusters = &tri;
    info.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    BuildSizes implicit = cluster_build_sizes(info, p);
    info.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    BuildSizes explicit_sizes = cluster_build_sizes(info, p);
    EXPECT_GE(implicit.acceleration_structure_size,
              10 * explicit_sizes.acceleration_structure_size);
    EXPECT_EQ(implicit.build_scratch_size, 160u);
    EXPECT_EQ(implicit.update_scratch_size, 0u);
    // Counts near 2^32 saturate instead of wrapping.
    info.maxAccelerationStructureCount = 0xFFFFFFFFu;
    tri.maxClusterTriangleCount = 0xFFFFFFFFu;
    tri.maxClusterVertexCount = 0xFFFFFFFFu;
    info.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    BuildSizes huge = cluster_build_sizes(info, p);
    EXPECT_GE(huge.acceleration_structure_size, 0xFFFFFFFFull);
    info.opInput.pTriangleClusters = nullptr;
    EXPECT_EQ(
        count_rule(cluster_build_sizes(info, p).findings,
                   "VUID-VkClusterAccelerationStructureInputInfoNV-pTriangleClusters-parameter"),
        1u);
    info.opType = VkClusterAccelerationStructureOpTypeNV(77);
    EXPECT_EQ(cluster_build_sizes(info, p).findings.size(), 1u);
}

}  // namespace
}  // namespace clastrace::engine::execute_test
