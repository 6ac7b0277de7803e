// SPDX-License-Identifier: Apache-2.0
// The address rules broken through an INDIRECTED_* flag: the command's field holds the address
// of a cell, the cell holds the bad value (docs/spec-readings.md: a strided region's cell holds
// its deviceAddress only). The cells lie in memory of unknown usage, so a rule reported here was
// judged on the value read through the cell, not on the field. Each rule has a twin whose cell
// holds a good value.
#include "execute_rig.h"

namespace clastrace::engine::execute_test {
namespace {

const auto kBuild = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
const auto kImplicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
const std::string kCommandRule = "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-";

constexpr uint64_t kNoStorage = 0x600000000ull;     // TRANSFER_DST only
constexpr uint64_t kStorageOnly = 0x610000000ull;   // STORAGE_BUFFER only
constexpr uint64_t kNoBuildInput = 0x620000000ull;  // STORAGE_BUFFER only, 1 MiB
constexpr uint64_t kRegionBytes = 1 << 20;

// One implicit triangle-cluster build, plus buffers that each lack one usage bit.
struct IndirectionRig {
    Rig rig;
    ClusteredMesh mesh = icosphere_meshlets(2);
    uint32_t count = uint32_t(mesh.clusters.size());
    uint64_t infos = upload_cluster_infos(rig, mesh);
    CommandSetup setup;

    IndirectionRig() {
        rig.memory.add_region(kNoStorage, kRegionBytes, VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                              "without STORAGE");
        rig.memory.add_region(kStorageOnly, kRegionBytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                              "without AS_STORAGE");
        rig.memory.add_region(kNoBuildInput, kRegionBytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                              "without BUILD_INPUT");
        setup_command(setup, rig, kBuild, kImplicit, count, infos);
    }

    // Puts `value` in a fresh cell, sets `flag` and aims `field` at the cell.
    void indirect(uint64_t& field, uint32_t flag, uint64_t value) {
        const uint64_t cell = Rig::alloc(rig.arrays, 8, 8);
        rig.memory.write<uint64_t>(cell, value, {"cell", -1});
        field = cell;
        setup.cmd.addressResolutionFlags |= flag;
    }

    size_t count_of(const std::string& number) {
        const ExecutionRecord r = execute(setup.cmd, rig.memory);
        last_findings = describe(r.findings);
        return count_rule(r.findings, kCommandRule + number);
    }

    // A copy of the src infos at `address` (a buffer the test added).
    uint64_t copy_infos_to(uint64_t address) {
        const uint64_t bytes =
            uint64_t(count) * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
        const auto source = rig.memory.read_bytes(infos, bytes, {"t", -1});
        const std::vector<std::byte> copy(source.begin(), source.end());
        std::copy(copy.begin(), copy.end(),
                  rig.memory.write_bytes(address, bytes, {"t", -1}).begin());
        return address;
    }

    std::string last_findings;
};

const uint32_t kScratchBit =
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV;
const uint32_t kImplicitBit =
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV;
const uint32_t kSrcInfosBit =
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV;
const uint32_t kCountBit =
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV;
const uint32_t kDstAddressesBit =
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV;

TEST(IndirectedRules, ScratchTooSmallThroughTheCellIs12300) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t good = t.setup.cmd.scratchData;
        // An aligned buffer of 32 bytes, fewer than the build sizes ask for.
        const uint64_t small = 0x640000000ull;
        t.rig.memory.add_region(small, 32, 0, "32 bytes");
        ASSERT_GT(cluster_build_sizes(t.setup.cmd.input, EngineProperties::nvidia_default())
                      .build_scratch_size,
                  32u);
        t.indirect(t.setup.cmd.scratchData, kScratchBit, broken ? small : good);
        EXPECT_EQ(t.count_of("scratchData-12300"), broken ? 1u : 0u) << t.last_findings;
        EXPECT_EQ(t.count_of("scratchData-12301"), 0u) << t.last_findings;
    }
}

TEST(IndirectedRules, MisalignedScratchThroughTheCellIs12301) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t good = t.setup.cmd.scratchData;
        t.indirect(t.setup.cmd.scratchData, kScratchBit, broken ? good + 8 : good);
        EXPECT_EQ(t.count_of("scratchData-12301"), broken ? 1u : 0u) << t.last_findings;
    }
}

TEST(IndirectedRules, ImplicitDataOverlappingScratchThroughTheCellIs12303) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t implicit_data = t.setup.cmd.dstImplicitData;
        if (broken) t.setup.cmd.scratchData = implicit_data + 256;
        t.indirect(t.setup.cmd.dstImplicitData, kImplicitBit, implicit_data);
        EXPECT_EQ(t.count_of("dstImplicitData-12303"), broken ? 1u : 0u) << t.last_findings;
    }
}

TEST(IndirectedRules, ScratchWithoutStorageUsageThroughTheCellIs12304) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t good = t.setup.cmd.scratchData;
        t.indirect(t.setup.cmd.scratchData, kScratchBit, broken ? kNoStorage : good);
        EXPECT_EQ(t.count_of("pCommandInfos-12304"), broken ? 1u : 0u) << t.last_findings;
    }
}

TEST(IndirectedRules, SrcInfosWithoutBuildInputUsageThroughTheCellIs12305) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t infos = broken ? t.copy_infos_to(kNoBuildInput) : t.infos;
        t.indirect(t.setup.cmd.srcInfosArray.deviceAddress, kSrcInfosBit, infos);
        EXPECT_EQ(t.count_of("pCommandInfos-12305"), broken ? 1u : 0u) << t.last_findings;
        // The ops ran from the infos behind the cell: the stride and size stayed the command's.
        EXPECT_EQ(execute(t.setup.cmd, t.rig.memory).op_count, t.count);
    }
}

TEST(IndirectedRules, CountWithoutBuildInputUsageThroughTheCellIs12306) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t count_address = broken ? kNoBuildInput : Rig::alloc(t.rig.arrays, 4, 4);
        t.rig.memory.write<uint32_t>(count_address, t.count, {"t", -1});
        t.indirect(t.setup.cmd.srcInfosCount, kCountBit, count_address);
        EXPECT_EQ(t.count_of("pCommandInfos-12306"), broken ? 1u : 0u) << t.last_findings;
    }
}

TEST(IndirectedRules, DstAddressesWithoutStorageUsageThroughTheCellIs12307) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t good = t.setup.cmd.dstAddressesArray.deviceAddress;
        t.indirect(t.setup.cmd.dstAddressesArray.deviceAddress, kDstAddressesBit,
                   broken ? kStorageOnly : good);
        EXPECT_EQ(t.count_of("pCommandInfos-12307"), broken ? 1u : 0u) << t.last_findings;
    }
}

TEST(IndirectedRules, ImplicitDataWithoutStorageUsageThroughTheCellIs12308) {
    for (bool broken : {true, false}) {
        IndirectionRig t;
        const uint64_t good = t.setup.cmd.dstImplicitData;
        t.indirect(t.setup.cmd.dstImplicitData, kImplicitBit, broken ? kStorageOnly : good);
        EXPECT_EQ(t.count_of("pCommandInfos-12308"), broken ? 1u : 0u) << t.last_findings;
    }
}

}  // namespace
}  // namespace clastrace::engine::execute_test
