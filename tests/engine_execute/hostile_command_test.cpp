// SPDX-License-Identifier: Apache-2.0
// Hostile commands: findings, never crashes, hangs or runaway memory.
#include "execute_rig.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>

namespace clastrace::engine::execute_test {
namespace {

const auto kBuild = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
const auto kBlas = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
const auto kImplicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
const auto kExplicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
const auto kSizes = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
const char* k10454 = "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10454";

TEST(HostileCommand, MaxCountOfFourBillionRunsOnlyWhatMemoryHolds) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(3);
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    setup_command(s, rig, kBuild, kSizes, 1, infos);
    s.cmd.input.maxAccelerationStructureCount = 0xFFFFFFFFu;
    // srcInfosArray's last 10 infos sit at the end of the inputs region.
    const uint64_t info = sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    s.cmd.srcInfosArray.deviceAddress = rig.inputs.base + rig.inputs.size - 10 * info;
    s.cmd.dstSizesArray = {Rig::alloc(rig.arrays, 64, 8), 4, 0};
    ExecutionRecord r = execute(s.cmd, rig.memory);
    EXPECT_EQ(count_rule(r.findings, k10454), 1u) << describe(r.findings);
    EXPECT_EQ(r.op_count, 10u);
    // Also through srcInfosCount holding 2^32 - 1.
    uint32_t all = 0xFFFFFFFFu;
    s.cmd.srcInfosCount = rig.put(rig.arrays, &all, 4, 4);
    r = execute(s.cmd, rig.memory);
    EXPECT_EQ(count_rule(r.findings, k10454), 1u) << describe(r.findings);
    EXPECT_EQ(r.op_count, 10u);
    // And with srcInfosArray.size smaller than the count.
    s.cmd.srcInfosArray = {infos, 0, 3 * info + 5};
    r = execute(s.cmd, rig.memory);
    EXPECT_EQ(count_rule(r.findings, k10454), 1u) << describe(r.findings);
    EXPECT_EQ(r.op_count, 3u);
}

TEST(HostileCommand, FindingsPerRuleAreCapped) {
    Rig rig(2);
    // 2^17 zero-filled BLAS infos (the whole inputs region): every op breaks the same rules.
    CommandSetup s;
    setup_command(s, rig, kBlas, kSizes, 1, rig.inputs.base);
    s.cmd.input.maxAccelerationStructureCount = 0xFFFFFFFFu;
    s.cmd.dstSizesArray = {};
    s.cmd.scratchData = 0;
    s.bottom.maxClusterCountPerAccelerationStructure = 0;
    // Each zero info has count 0, which is fine; make them reference something missing.
    std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> infos(1 << 16,
                                                                                    {1, 8, 0x42});
    rig.put_vec(rig.inputs, infos, 16);
    ExecuteOptions o;
    o.max_findings_per_rule = 16;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    EXPECT_EQ(r.op_count, (2u << 20) / 16);
    EXPECT_LE(r.findings.size(), 16u * 8);
    EXPECT_GE(count_rule(r.findings, kRuleFindingsTruncated), 1u) << describe(r.findings);
}

TEST(HostileCommand, OverflowingStridesAreFindings) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(3);
    uint64_t infos = upload_cluster_infos(rig, m);
    {
        // srcInfosArray stride near 2^64: only element 0 exists.
        CommandSetup s;
        setup_command(s, rig, kBuild, kImplicit, 4, infos);
        s.cmd.srcInfosArray.stride = ~0ull - 7;
        ExecutionRecord r = execute(s.cmd, rig.memory);
        EXPECT_EQ(count_rule(r.findings, k10454), 1u) << describe(r.findings);
        EXPECT_EQ(r.op_count, 1u);
    }
    {
        // dstAddressesArray stride 2^63 in explicit mode: op 0 works, op 1's element wraps.
        CommandSetup s;
        setup_command(s, rig, kBuild, kExplicit, 2, infos);
        rig.memory.write<uint64_t>(s.cmd.dstAddressesArray.deviceAddress,
                                   Rig::alloc(rig.objects2, 8192), {"t", -1});
        s.cmd.dstAddressesArray.stride = 1ull << 63;
        s.cmd.dstAddressesArray.size = 0;
        s.cmd.dstSizesArray = {};
        ExecutionRecord r = execute(s.cmd, rig.memory);
        EXPECT_TRUE(r.ops[0].executed);
        EXPECT_FALSE(r.ops[1].executed);
        EXPECT_EQ(count_rule(r.findings, kRuleMemoryFault), 1u) << describe(r.findings);
    }
    {
        // srcInfosArray stride smaller than the struct.
        CommandSetup s;
        setup_command(s, rig, kBuild, kImplicit, 4, infos);
        s.cmd.srcInfosArray.stride = 8;
        ExecutionRecord r = execute(s.cmd, rig.memory);
        EXPECT_EQ(
            count_rule(r.findings,
                       "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10450"),
            1u)
            << describe(r.findings);
        EXPECT_EQ(r.op_count, 0u);
    }
}

TEST(HostileCommand, HostileBottomLevelReferences) {
    Rig rig;
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(2);
    auto clas = build_clas(rig, m, &dir);
    std::vector<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV> infos = {
        {0xFFFFFFFFu, 8, rig.inputs.base},  // count 2^32-1: runs off the region
        {2, 0xFFFFFFFFu, rig.inputs.base},  // stride 2^32-1: the second reference is outside memory
        {2, 4, rig.inputs.base},            // stride < 8
        {2, 8, 0},                          // references at address 0
        {3, 8, 0},                          // (filled below) references into the info array itself
        {2, 8, 0},                          // (filled below) the same CLAS twice
    };
    uint64_t info_address = Rig::alloc(rig.inputs, infos.size() * sizeof infos[0], 16);
    infos[4].clusterReferences = info_address;  // "addresses" are the info structs' own bytes
    std::vector<uint64_t> dup = {clas[0], clas[0]};
    infos[5].clusterReferences = rig.put_vec(rig.inputs, dup, 8);
    std::memcpy(
        rig.memory.write_bytes(info_address, infos.size() * sizeof infos[0], {"t", -1}).data(),
        infos.data(), infos.size() * sizeof infos[0]);
    CommandSetup s;
    setup_command(s, rig, kBlas, kImplicit, uint32_t(infos.size()), info_address);
    s.bottom.maxClusterCountPerAccelerationStructure = 0xFFFFFFFFu;
    s.bottom.maxTotalClusterCount = 0xFFFFFFFFu;
    ExecuteOptions o;
    o.directory = &dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    const char* k10485 =
        "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-clusterReferences-10485";
    EXPECT_EQ(count_rule(r.findings, k10485), 3u) << describe(r.findings);  // ops 0, 1, 3
    EXPECT_EQ(count_rule(r.findings,
                         "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-"
                         "clusterReferencesStride-10486"),
              1u);
    EXPECT_EQ(count_rule(r.findings, kRuleStaleClusterReference), 3u)
        << describe(r.findings);  // op 4's three
    EXPECT_EQ(count_rule(r.findings,
                         "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-"
                         "clusterReferences-10484"),
              1u);
    EXPECT_TRUE(r.ops[4].executed);  // built from its valid references: none
    EXPECT_TRUE(r.ops[5].executed);
}

TEST(HostileCommand, DestinationsPointingIntoTheCommandsOwnArrays) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(3);
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    setup_command(s, rig, kBuild, kExplicit, 3, infos);
    // Op 0's object lands on the dstAddressesArray itself, op 1's on srcInfosArray, op 2's on op 1's.
    uint64_t arr = s.cmd.dstAddressesArray.deviceAddress;
    uint64_t shared = Rig::alloc(rig.objects2, 4096);
    uint64_t dsts[3] = {arr, infos, shared};
    std::memcpy(rig.memory.write_bytes(arr, 24, {"t", -1}).data(), dsts, 24);
    s.cmd.dstSizesArray = {};
    // Misalign: arr is 8-aligned only.
    ExecutionRecord r1 = execute(s.cmd, rig.memory);
    EXPECT_GE(count_rule(r1.findings, kRuleIntraCommandHazard), 2u) << describe(r1.findings);
    EXPECT_GE(count_rule(r1.findings, kRuleDestinationMisaligned), 1u) << describe(r1.findings);
    // The same command on a fresh copy of the inputs gives the same bytes (reads precede writes).
    Rig rig2;
    uint64_t infos2 = upload_cluster_infos(rig2, m);
    ASSERT_EQ(infos2, infos);
    CommandSetup s2;
    setup_command(s2, rig2, kBuild, kExplicit, 3, infos2);
    Rig::alloc(rig2.objects2, 4096);
    std::memcpy(rig2.memory.write_bytes(arr, 24, {"t", -1}).data(), dsts, 24);
    s2.cmd.dstSizesArray = {};
    ExecutionRecord r2 = execute(s2.cmd, rig2.memory);
    EXPECT_EQ(rig.snapshot(), rig2.snapshot());
    EXPECT_EQ(r1.findings.size(), r2.findings.size());
}

TEST(HostileCommand, SelfReferentialIndirection) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(3);
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    setup_command(s, rig, kBuild, kSizes, 4, infos);
    // srcInfosCount indirected through a cell that holds its own address.
    uint64_t cell = Rig::alloc(rig.arrays, 8, 8);
    rig.memory.write<uint64_t>(cell, cell, {"t", -1});
    s.cmd.srcInfosCount = cell;
    s.cmd.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV |
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV;
    s.cmd.scratchData = 0x1234;  // indirected through unmapped memory
    ExecutionRecord r = execute(s.cmd, rig.memory);
    EXPECT_EQ(count_rule(r.findings, kRuleMemoryFault), 1u) << describe(r.findings);
    EXPECT_EQ(r.op_count, 0u);
    s.cmd.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV;
    s.cmd.scratchData = Rig::alloc(rig.scratch, 64);
    r = execute(s.cmd, rig.memory);
    // The count read is the cell's low 32 bits, far above the max: capped with 10453.
    EXPECT_EQ(
        count_rule(r.findings,
                   "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453"),
        1u)
        << describe(r.findings);
    EXPECT_EQ(r.op_count, 4u);
}

// Deterministic random mutation of whole commands' memory: findings, never a crash.
TEST(HostileCommand, RandomMutationsNeverCrash) {
    std::mt19937_64 rng(12345);
    for (int type = 0; type < 6; ++type) {
        Rig rig(1);  // ops scale with the memory that exists: 1 MiB keeps this fast
        ObjectDirectory dir;
        ClusteredMesh m = icosphere_meshlets(2);
        auto clas = build_clas(rig, m, &dir);
        uint64_t blas = build_blas(rig, clas, &dir);
        uint64_t tinfos = upload_cluster_infos(rig, m, true);
        CommandSetup ts;
        setup_command(ts, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                      kImplicit, uint32_t(m.clusters.size()), tinfos);
        ExecuteOptions o;
        o.directory = &dir;
        claim_implicit(rig, execute(ts.cmd, rig.memory, o));
        uint64_t cinfos = upload_cluster_infos(rig, m);
        std::vector<uint64_t> addresses = clas;
        addresses.push_back(blas);
        uint64_t moves = rig.put_vec(rig.inputs, addresses, 16);
        uint64_t blas_info = upload_blas_info(rig, clas);
        const uint64_t objects_reset = rig.objects.next, scratch_reset = rig.scratch.next,
                       arrays_reset = rig.arrays.next;
        for (int trial = 0; trial < 40; ++trial) {
            CommandSetup s;
            uint64_t src = type == 0 ? moves : type == 1 ? blas_info : type == 3 ? tinfos : cinfos;
            setup_command(s, rig, VkClusterAccelerationStructureOpTypeNV(type),
                          VkClusterAccelerationStructureOpModeNV(trial % 3), 4, src);
            s.move.type = VkClusterAccelerationStructureTypeNV(rng() % 3);
            s.move.noMoveOverlap = VK_TRUE;
            // Flip bits anywhere in the inputs (infos, buffers, objects) and sometimes in the command.
            for (int k = 0; k < 8; ++k) {
                uint64_t a = rig.inputs.base + rng() % (rig.inputs.next - rig.inputs.base);
                auto b = rig.memory.write_bytes(a, 1, {"t", -1});
                b[0] ^= std::byte(1u << (rng() % 8));
            }
            for (int k = 0; k < 2; ++k) {
                uint64_t a = rig.objects.base + rng() % (rig.objects.next - rig.objects.base);
                auto b = rig.memory.write_bytes(a, 1, {"t", -1});
                b[0] ^= std::byte(1u << (rng() % 8));
            }
            if (trial % 5 == 0) s.cmd.srcInfosArray.stride = rng() % 256;
            if (trial % 7 == 0) s.cmd.addressResolutionFlags = uint32_t(rng() % 64);
            if (trial % 11 == 0) s.cmd.input.maxAccelerationStructureCount = uint32_t(rng());
            ExecutionRecord r;
            auto t0 = std::chrono::steady_clock::now();
            ASSERT_NO_THROW(r = execute(s.cmd, rig.memory, o));
            double ms =
                std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                    .count();
            if (getenv("HOSTILE_COMMAND_TRACE_SLOW") && ms > 200)
                std::printf("type %d trial %d: %.0f ms, %u ops, mode %d, stride %llu\n", type,
                            trial, ms, r.op_count, trial % 3,
                            (unsigned long long)s.cmd.srcInfosArray.stride);
            EXPECT_LE(r.findings.size(), 64u * 40);
            // Later commands may overwrite these outputs: that is part of the mutation.
            rig.objects.next = objects_reset;
            rig.scratch.next = scratch_reset;
            rig.arrays.next = arrays_reset;
        }
    }
}

}  // namespace
}  // namespace clastrace::engine::execute_test
