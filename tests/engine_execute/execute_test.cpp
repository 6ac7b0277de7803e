// SPDX-License-Identifier: Apache-2.0
// execute(): packing, the count rules, scratch, and the execution record.
#include "execute_rig.h"

#include "clastrace/common/enum_bits.h"
#include "clastrace/engine/cluster_format.h"

namespace clastrace::engine::execute_test {
namespace {

const auto kBuild = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
const auto kImplicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
const auto kSizes = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;

const MemoryAccess* find_access(const ExecutionRecord& r, const std::string& field) {
    for (const auto& a : r.accesses)
        if (a.field == field) return &a;
    return nullptr;
}

TEST(Execute, ImplicitBuildPacksInOpOrderAtClusterAlignment) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(2);
    ASSERT_GT(m.clusters.size(), 2u);
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    const uint32_t n = uint32_t(m.clusters.size());
    setup_command(s, rig, kBuild, kImplicit, n, infos);
    ExecutionRecord r = execute(s.cmd, rig.memory);
    ASSERT_TRUE(r.findings.empty()) << describe(r.findings);
    ASSERT_EQ(r.op_count, n);
    auto addrs = dst_addresses(rig, s.cmd, n);
    const uint64_t align = EngineProperties{}.cluster_byte_alignment;
    uint64_t expect = s.cmd.dstImplicitData;
    for (uint32_t i = 0; i < n; ++i) {
        expect = (expect + align - 1) / align * align;
        EXPECT_EQ(addrs[i], expect) << "op " << i;
        uint32_t size = rig.get<uint32_t>(s.cmd.dstSizesArray.deviceAddress + 4ull * i);
        EXPECT_EQ(size, r.ops[i].dst_size);
        auto h = read_object_header(rig.bytes(addrs[i], size));
        ASSERT_TRUE(h.header) << h.error;
        EXPECT_EQ(h.header->cluster_id, i);
        EXPECT_EQ(h.header->triangle_count, m.clusters[i].triangles.size() / 3);
        expect += size;
    }
    EXPECT_EQ(r.implicit_bytes_used, expect - s.cmd.dstImplicitData);
}

TEST(Execute, RecordNamesEveryRangeWithTheSpecStageAndAccess) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(2);
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    const uint32_t n = uint32_t(m.clusters.size());
    setup_command(s, rig, kBuild, kImplicit, n, infos);
    uint64_t count_cell = rig.put(rig.arrays, &n, 4, 4);
    s.cmd.srcInfosCount = count_cell;
    ExecutionRecord r = execute(s.cmd, rig.memory);
    ASSERT_TRUE(r.findings.empty()) << describe(r.findings);
    for (const auto& a : r.accesses)
        EXPECT_EQ(a.stage, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);

    const MemoryAccess* count = find_access(r, "srcInfosCount");
    ASSERT_NE(count, nullptr);
    EXPECT_EQ(count->begin, count_cell);
    EXPECT_EQ(count->end, count_cell + 4);
    EXPECT_EQ(count->access, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    EXPECT_FALSE(count->is_write);

    const MemoryAccess* info0 = find_access(r, "srcInfosArray[0]");
    ASSERT_NE(info0, nullptr);
    EXPECT_EQ(info0->begin, infos);
    EXPECT_EQ(info0->end - info0->begin,
              sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV));
    EXPECT_EQ(info0->access, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    EXPECT_EQ(info0->op_index, 0);

    VkClusterAccelerationStructureBuildTriangleClusterInfoNV i1;
    std::memcpy(&i1, rig.bytes(infos + sizeof i1, sizeof i1).data(), sizeof i1);
    const MemoryAccess* vb = find_access(r, "srcInfosArray[1].vertexBuffer");
    ASSERT_NE(vb, nullptr);
    EXPECT_EQ(vb->begin, i1.vertexBuffer);
    EXPECT_EQ(vb->end, i1.vertexBuffer + 12ull * i1.vertexCount);
    EXPECT_EQ(vb->op_index, 1);
    EXPECT_FALSE(vb->is_write);
    const MemoryAccess* ib = find_access(r, "srcInfosArray[1].indexBuffer");
    ASSERT_NE(ib, nullptr);
    EXPECT_EQ(ib->end - ib->begin, 3ull * i1.triangleCount);

    const MemoryAccess* scratch = find_access(r, "scratchData");
    ASSERT_NE(scratch, nullptr);
    EXPECT_EQ(scratch->begin, s.cmd.scratchData);
    EXPECT_EQ(scratch->end - scratch->begin, 16ull * n);
    EXPECT_EQ(scratch->access, VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                   VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    EXPECT_TRUE(scratch->is_write);

    auto addrs = dst_addresses(rig, s.cmd, n);
    const MemoryAccess* obj = find_access(r, "dstImplicitData[op 2]");
    ASSERT_NE(obj, nullptr);
    EXPECT_EQ(obj->begin, addrs[2]);
    EXPECT_EQ(obj->end, addrs[2] + r.ops[2].dst_size);
    EXPECT_EQ(obj->access, VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    EXPECT_TRUE(obj->is_write);
    const MemoryAccess* da = find_access(r, "dstAddressesArray[2]");
    ASSERT_NE(da, nullptr);
    EXPECT_TRUE(da->is_write);
    EXPECT_EQ(da->begin, s.cmd.dstAddressesArray.deviceAddress + 16);
    const MemoryAccess* ds = find_access(r, "dstSizesArray[2]");
    ASSERT_NE(ds, nullptr);
    EXPECT_EQ(ds->begin, s.cmd.dstSizesArray.deviceAddress + 8);
    EXPECT_EQ(ds->end - ds->begin, 4u);
}

TEST(Execute, CountIsMinOfMemoryAndMaxAndZeroAddressMeansMax) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(3);
    ASSERT_GT(m.clusters.size(), 5u);
    uint64_t infos = upload_cluster_infos(rig, m);
    const uint32_t n = uint32_t(m.clusters.size());
    {
        CommandSetup s;
        setup_command(s, rig, kBuild, kSizes, n, infos);
        uint32_t three = 3;
        s.cmd.srcInfosCount = rig.put(rig.arrays, &three, 4, 4);
        ExecutionRecord r = execute(s.cmd, rig.memory);
        EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
        EXPECT_EQ(r.op_count, 3u);
    }
    {
        CommandSetup s;
        setup_command(s, rig, kBuild, kSizes, 4, infos);
        uint32_t many = n;
        s.cmd.srcInfosCount = rig.put(rig.arrays, &many, 4, 4);
        ExecutionRecord r = execute(s.cmd, rig.memory);
        EXPECT_EQ(r.op_count, 4u);
        EXPECT_EQ(
            count_rule(r.findings,
                       "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453"),
            1u)
            << describe(r.findings);
    }
    {
        CommandSetup s;
        setup_command(s, rig, kBuild, kSizes, 5, infos);
        s.cmd.srcInfosCount = 0;
        ExecutionRecord r = execute(s.cmd, rig.memory);
        EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
        EXPECT_EQ(r.op_count, 5u);
    }
}

TEST(Execute, ComputeSizesWritesSizesAndScratchOnly) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(2);
    uint64_t infos = upload_cluster_infos(rig, m);
    const uint32_t n = uint32_t(m.clusters.size());
    CommandSetup implicit_s;
    setup_command(implicit_s, rig, kBuild, kImplicit, n, infos);
    ExecutionRecord built = execute(implicit_s.cmd, rig.memory);
    claim_implicit(rig, built);
    CommandSetup s;
    setup_command(s, rig, kBuild, kSizes, n, infos);
    auto before = rig.snapshot();
    ExecutionRecord r = execute(s.cmd, rig.memory);
    ASSERT_TRUE(r.findings.empty()) << describe(r.findings);
    auto after = rig.snapshot();
    for (uint32_t i = 0; i < n; ++i)
        EXPECT_EQ(rig.get<uint32_t>(s.cmd.dstSizesArray.deviceAddress + 4ull * i),
                  built.ops[i].dst_size);
    // Byte by byte: only dstSizesArray and the scratch table changed.
    for (const auto& [base, bytes] : before) {
        const auto& now = after.at(base);
        for (size_t k = 0; k < bytes.size(); ++k) {
            if (bytes[k] == now[k]) continue;
            uint64_t a = base + k;
            bool sizes = a >= s.cmd.dstSizesArray.deviceAddress &&
                         a < s.cmd.dstSizesArray.deviceAddress + 4ull * n;
            bool scratch = a >= s.cmd.scratchData && a < s.cmd.scratchData + 16ull * n;
            ASSERT_TRUE(sizes || scratch) << "compute-sizes wrote " << std::hex << a;
        }
    }
    for (const auto& a : r.accesses)
        if (a.is_write) {
            EXPECT_TRUE(a.field.starts_with("dstSizesArray") || a.field == "scratchData")
                << a.field;
        }
}

TEST(Execute, ScratchTooSmallAndMisalignedAreFindings) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(1);
    uint64_t infos = upload_cluster_infos(rig, m);
    const uint32_t n = uint32_t(m.clusters.size());
    CommandSetup s;
    setup_command(s, rig, kBuild, kImplicit, n, infos);
    // 8 bytes before the end of the scratch region, and not 128-aligned.
    s.cmd.scratchData = rig.scratch.base + rig.scratch.size - 8;
    ExecutionRecord r = execute(s.cmd, rig.memory);
    EXPECT_EQ(count_rule(r.findings, kRuleScratchTooSmall), 1u) << describe(r.findings);
    EXPECT_EQ(count_rule(r.findings, kRuleScratchMisaligned), 1u) << describe(r.findings);
    // The ops still ran: scratch faults do not stop the build.
    EXPECT_TRUE(r.ops[0].executed);
}

TEST(Execute, ImplicitOverlappingScratchIs12303) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(1);
    uint64_t infos = upload_cluster_infos(rig, m);
    const uint32_t n = uint32_t(m.clusters.size());
    CommandSetup s;
    setup_command(s, rig, kBuild, kImplicit, n, infos);
    s.cmd.scratchData = s.cmd.dstImplicitData + 256;
    ExecutionRecord r = execute(s.cmd, rig.memory);
    EXPECT_EQ(
        count_rule(r.findings,
                   "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstImplicitData-12303"),
        1u)
        << describe(r.findings);
}

TEST(Execute, BufferUsageRulesWhenTheTraceRecordedUsage) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(2);
    uint64_t infos = upload_cluster_infos(rig, m);
    const uint32_t n = uint32_t(m.clusters.size());
    // Buffers with recorded usage, each missing the bit its field requires.
    rig.memory.add_region(0x600000000ull, 1 << 16, VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                          "scratch without STORAGE");
    rig.memory.add_region(0x610000000ull, 1 << 20, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                          "implicit without AS_STORAGE");
    rig.memory.add_region(0x620000000ull, 1 << 12, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                          "count without BUILD_INPUT");
    CommandSetup s;
    setup_command(s, rig, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                  kImplicit, n, infos);
    s.cmd.scratchData = 0x600000000ull;
    s.cmd.dstImplicitData = 0x610000000ull;
    rig.memory.write<uint32_t>(0x620000000ull, n, {"t", -1});
    s.cmd.srcInfosCount = 0x620000000ull;
    ExecutionRecord r = execute(s.cmd, rig.memory);
    for (const char* vuid :
         {"VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12304",
          "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12306",
          "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12308"})
        EXPECT_EQ(count_rule(r.findings, vuid), 1u) << vuid << "\n" << describe(r.findings);
    // Unknown usage (0) is never a finding: the inputs region above.
    EXPECT_EQ(
        count_rule(r.findings,
                   "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12305"),
        0u);
    EXPECT_TRUE(r.ops[0].executed);
}

// The usage table's rows keep the order findings always had: the address rows before the
// op count is read (10453), the element-range rows after it.
TEST(Execute, BufferUsageFindingsComeInStageOrder) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(2);
    const uint64_t uploaded = upload_cluster_infos(rig, m);
    const uint32_t n = uint32_t(m.clusters.size());
    const uint64_t info_bytes =
        uint64_t(n) * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    const uint64_t infos = 0x630000000ull, dst_addresses = 0x640000000ull;
    rig.memory.add_region(0x600000000ull, 1 << 16, VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                          "scratch without STORAGE");
    rig.memory.add_region(0x610000000ull, 1 << 20, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                          "implicit without AS_STORAGE");
    rig.memory.add_region(0x620000000ull, 1 << 12, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                          "count without BUILD_INPUT");
    rig.memory.add_region(infos, info_bytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                          "infos without BUILD_INPUT");
    rig.memory.add_region(dst_addresses, 8 * n, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                          "addresses without AS_STORAGE");
    const auto bytes = rig.memory.read_bytes(uploaded, info_bytes, {"t", -1});
    const std::vector<std::byte> copy(bytes.begin(), bytes.end());
    std::copy(copy.begin(), copy.end(),
              rig.memory.write_bytes(infos, info_bytes, {"t", -1}).begin());
    CommandSetup s;
    setup_command(s, rig, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                  kImplicit, n, infos);
    s.cmd.scratchData = 0x600000000ull;
    s.cmd.dstImplicitData = 0x610000000ull;
    s.cmd.dstAddressesArray = {dst_addresses, 8, 8 * n};
    rig.memory.write<uint32_t>(0x620000000ull, n + 1, {"t", -1});  // above the max: 10453
    s.cmd.srcInfosCount = 0x620000000ull;
    ExecutionRecord r = execute(s.cmd, rig.memory);
    const std::string prefix =
        "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-";
    std::vector<std::string> order;
    for (const Finding& f : r.findings)
        for (const char* number : {"12304", "12305", "12306", "12307", "12308", "10453"})
            if (f.rule == prefix + number) order.push_back(number);
    EXPECT_EQ(order,
              (std::vector<std::string>{"12304", "12306", "12308", "10453", "12305", "12307"}))
        << describe(r.findings);
}

TEST(Execute, ZeroAlignmentsInCapturedPropertiesDoNotCrash) {
    Rig rig;
    ClusteredMesh m = icosphere_meshlets(2);
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    setup_command(s, rig, kBuild, kImplicit, uint32_t(m.clusters.size()), infos);
    ExecuteOptions o;
    o.properties.cluster_byte_alignment = 0;
    o.properties.cluster_scratch_byte_alignment = 0;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
    EXPECT_TRUE(r.ops[0].executed);
    auto in = s.cmd.input;
    EXPECT_GT(cluster_build_sizes(in, o.properties).acceleration_structure_size, 0u);
}

TEST(Execute, BadOpTypeModeAndMissingInputAreFindings) {
    Rig rig;
    CommandSetup s;
    setup_command(s, rig, kBuild, kImplicit, 1, rig.inputs.base);
    s.cmd.input.opType = VkClusterAccelerationStructureOpTypeNV(9);
    EXPECT_EQ(count_rule(execute(s.cmd, rig.memory).findings,
                         "VUID-VkClusterAccelerationStructureInputInfoNV-opType-parameter"),
              1u);
    s.cmd.input.opType = kBuild;
    s.cmd.input.opMode = VkClusterAccelerationStructureOpModeNV(7);
    EXPECT_EQ(count_rule(execute(s.cmd, rig.memory).findings,
                         "VUID-VkClusterAccelerationStructureInputInfoNV-opMode-parameter"),
              1u);
    s.cmd.input.opMode = kImplicit;
    s.cmd.input.opInput.pTriangleClusters = nullptr;
    EXPECT_EQ(count_rule(execute(s.cmd, rig.memory).findings, kRuleMissingInput), 1u);
}

// The message of the one finding of `rule`, or "" when there is not exactly one.
std::string only_message(const std::vector<Finding>& findings, const char* rule) {
    if (count_rule(findings, rule) != 1) return "";
    for (const Finding& f : findings)
        if (f.rule == rule) return f.message;
    return "";
}

// A hostile trace may hold any 32 bits in an enum field: values past Vulkan's 0x7FFFFFFF are
// findings like any other bad value, found by the fields' bits (under UBSan, loading them as the
// enum stopped the check itself).
TEST(Execute, OpTypeAndModePastTheEnumsRangeAreFindings) {
    Rig rig;
    CommandSetup s;
    setup_command(s, rig, kBuild, kImplicit, 1, rig.inputs.base);
    common::set_enum_bits(s.cmd.input.opType, 0xffffffffu);
    const char* type_rule = "VUID-VkClusterAccelerationStructureInputInfoNV-opType-parameter";
    EXPECT_EQ(only_message(execute(s.cmd, rig.memory).findings, type_rule),
              "input.opType = -1 is not a VkClusterAccelerationStructureOpTypeNV");
    EXPECT_EQ(only_message(cluster_build_sizes(s.cmd.input, {}).findings, type_rule),
              "vkGetClusterAccelerationStructureBuildSizesNV: opType -1 is not a "
              "VkClusterAccelerationStructureOpTypeNV");
    s.cmd.input.opType = kBuild;
    common::set_enum_bits(s.cmd.input.opMode, 0x80000000u);
    const char* mode_rule = "VUID-VkClusterAccelerationStructureInputInfoNV-opMode-parameter";
    EXPECT_EQ(only_message(execute(s.cmd, rig.memory).findings, mode_rule),
              "input.opMode = -2147483648 is not a VkClusterAccelerationStructureOpModeNV");
    EXPECT_EQ(only_message(cluster_build_sizes(s.cmd.input, {}).findings, mode_rule),
              "vkGetClusterAccelerationStructureBuildSizesNV: opMode -2147483648 is not a "
              "VkClusterAccelerationStructureOpModeNV");
}

}  // namespace
}  // namespace clastrace::engine::execute_test
