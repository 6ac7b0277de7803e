// SPDX-License-Identifier: Apache-2.0
// Every op type x op mode x address-resolution flag: same objects, same sizes, no findings.
#include "execute_rig.h"

#include <tuple>

namespace clastrace::engine::execute_test {
namespace {

using Type = VkClusterAccelerationStructureOpTypeNV;
using Mode = VkClusterAccelerationStructureOpModeNV;

// A world with CLAS, templates and a BLAS to operate on; src infos for `type`.
struct World {
    Rig rig{16};
    ObjectDirectory dir;
    ClusteredMesh mesh = icosphere_meshlets(3);
    std::vector<uint64_t> clas, templates;
    uint64_t src_infos = 0;
    uint32_t count = 0;

    explicit World(Type type) {
        clas = build_clas(rig, mesh, &dir);
        uint64_t tinfos = upload_cluster_infos(rig, mesh, true);
        CommandSetup ts;
        setup_command(ts, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV,
                      uint32_t(mesh.clusters.size()), tinfos);
        ExecuteOptions o;
        o.directory = &dir;
        ExecutionRecord tr = execute(ts.cmd, rig.memory, o);
        EXPECT_TRUE(tr.findings.empty()) << describe(tr.findings);
        claim_implicit(rig, tr);
        templates = dst_addresses(rig, ts.cmd, uint32_t(mesh.clusters.size()));
        count = std::min<uint32_t>(6, uint32_t(mesh.clusters.size()));
        switch (type) {
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
            src_infos = rig.put_vec(rig.inputs,
                                    std::vector<uint64_t>(clas.begin(), clas.begin() + count), 16);
            break;
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: {
            count = 3;
            std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> infos;
            for (uint32_t b = 0; b < count; ++b) {
                std::vector<uint64_t> refs;
                for (size_t i = b; i < clas.size(); i += b + 1) refs.push_back(clas[i]);
                infos.push_back(
                    rig.get<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV>(
                        upload_blas_info(rig, refs)));
            }
            src_infos = rig.put_vec(rig.inputs, infos, 16);
            break;
        }
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
            src_infos = upload_cluster_infos(rig, mesh);
            break;
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
            src_infos = upload_cluster_infos(rig, mesh, true);
            break;
        case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: {
            std::vector<VkClusterAccelerationStructureInstantiateClusterInfoNV> inst(count);
            for (uint32_t c = 0; c < count; ++c) {
                inst[c].clusterIdOffset = 100;
                inst[c].clusterTemplateAddress = templates[c];
                inst[c].vertexBuffer = {rig.put_vec(rig.inputs, mesh.clusters[c].positions, 16),
                                        12};
            }
            src_infos = rig.put_vec(rig.inputs, inst, 16);
            break;
        }
        default:
            src_infos =
                rig.put_vec(rig.inputs,
                            std::vector<uint64_t>(templates.begin(), templates.begin() + count),
                            16);
            break;
        }
    }

    // Runs one command; moves copy (noMoveOverlap) so the world stays intact for the next.
    ExecutionRecord run(Type type, Mode mode, uint32_t flags, CommandSetup& s) {
        setup_command(s, rig, type, mode, count, src_infos);
        s.move.noMoveOverlap = VK_TRUE;
        s.cmd.srcInfosCount = rig.put(rig.arrays, &count, 4, 4);
        if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV) {
            for (uint32_t i = 0; i < count; ++i) {
                uint64_t dst = Rig::alloc(rig.objects2, 64 << 10, 256);
                rig.memory.write<uint64_t>(s.cmd.dstAddressesArray.deviceAddress + 8ull * i, dst,
                                           {"test", -1});
                rig.memory.write<uint32_t>(s.cmd.dstSizesArray.deviceAddress + 4ull * i, 64 << 10,
                                           {"test", -1});
            }
        }
        auto indirect = [&](uint64_t& field, uint32_t bit) {
            if ((flags & bit) && field != 0) field = rig.put(rig.arrays, &field, 8, 8);
        };
        auto& c = s.cmd;
        c.addressResolutionFlags = flags;
        indirect(
            c.dstImplicitData,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV);
        indirect(
            c.scratchData,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV);
        indirect(
            c.dstAddressesArray.deviceAddress,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV);
        indirect(
            c.dstSizesArray.deviceAddress,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV);
        indirect(
            c.srcInfosArray.deviceAddress,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV);
        indirect(
            c.srcInfosCount,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV);
        ExecuteOptions o;
        o.directory = &dir;
        ExecutionRecord r = execute(c, rig.memory, o);
        claim_implicit(rig, r);
        return r;
    }
};

class ExecuteOpMatrix : public ::testing::TestWithParam<std::tuple<int, int, uint32_t>> {};

TEST_P(ExecuteOpMatrix, SameObjectsInEveryModeAndIndirection) {
    const Type type = Type(std::get<0>(GetParam()));
    const Mode mode = Mode(std::get<1>(GetParam()));
    const uint32_t flags = std::get<2>(GetParam());
    World w(type);
    // Reference: implicit, no indirection.
    CommandSetup ref_setup;
    ExecutionRecord ref =
        w.run(type, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, 0,
              ref_setup);
    ASSERT_TRUE(ref.findings.empty()) << describe(ref.findings);
    std::vector<std::vector<std::byte>> ref_objects;
    for (const OpResult& op : ref.ops) {
        ASSERT_TRUE(op.executed);
        ref_objects.push_back(w.rig.bytes(op.dst_address, op.dst_size));
    }
    CommandSetup s;
    ExecutionRecord r = w.run(type, mode, flags, s);
    ASSERT_TRUE(r.findings.empty()) << describe(r.findings);
    ASSERT_EQ(r.op_count, w.count);
    for (uint32_t i = 0; i < w.count; ++i) {
        ASSERT_TRUE(r.ops[i].executed) << "op " << i;
        EXPECT_EQ(r.ops[i].dst_size, ref.ops[i].dst_size) << "op " << i;
        if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV) {
            EXPECT_EQ(r.ops[i].dst_address, 0u);
            continue;
        }
        EXPECT_EQ(w.rig.bytes(r.ops[i].dst_address, r.ops[i].dst_size), ref_objects[i])
            << "op " << i;
    }
    // Sizes land in dstSizesArray (implicit and compute-sizes write them; explicit reads them).
    uint64_t sizes_at = ref_setup.cmd.dstSizesArray.deviceAddress;
    if (mode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV) {
        sizes_at = s.cmd.dstSizesArray.deviceAddress;
        if (flags &
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV)
            sizes_at = w.rig.get<uint64_t>(sizes_at);
        for (uint32_t i = 0; i < w.count; ++i)
            EXPECT_EQ(w.rig.get<uint32_t>(sizes_at + 4ull * i), ref.ops[i].dst_size);
    }
    // Each indirection shows up as an indirect-command read of its 8-byte cell.
    size_t indirect_reads = 0;
    for (const auto& a : r.accesses)
        if (a.field.find("(indirected)") != std::string::npos) {
            EXPECT_EQ(a.access, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
            EXPECT_EQ(a.end - a.begin, 8u);
            ++indirect_reads;
        }
    size_t expected = 0;
    for (uint32_t bit = 1; bit <= 32; bit <<= 1) {
        if (!(flags & bit)) continue;
        bool used = true;
        if (bit ==
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV)
            used = mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
        if (bit ==
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV)
            used = mode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
        expected += used;
    }
    EXPECT_EQ(indirect_reads, expected);
}

std::string name(const ::testing::TestParamInfo<std::tuple<int, int, uint32_t>>& info) {
    static const char* types[] = {"Move",     "BottomLevel", "Cluster",
                                  "Template", "Instantiate", "TemplateIndices"};
    static const char* modes[] = {"Implicit", "Explicit", "Sizes"};
    return std::string(types[std::get<0>(info.param)]) + "_" + modes[std::get<1>(info.param)] +
           "_Flags" + std::to_string(std::get<2>(info.param));
}

INSTANTIATE_TEST_SUITE_P(AllOps, ExecuteOpMatrix,
                         ::testing::Combine(::testing::Range(0, 6), ::testing::Range(0, 3),
                                            ::testing::Values(0u, 1u, 2u, 4u, 8u, 16u, 32u, 63u)),
                         name);

}  // namespace
}  // namespace clastrace::engine::execute_test
