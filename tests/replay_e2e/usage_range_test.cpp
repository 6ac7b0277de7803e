// SPDX-License-Identifier: Apache-2.0
// VUIDs 12305 and 12307 over whole ranges: srcInfosArray and dstAddressesArray must be a
// "device address range" from buffers with the usage, not just their first byte. Each case is
// a broken/valid twin over aliased buffers: a large buffer without the usage, and over its
// start an alias with it. The alias covers only the first element (broken: the replay names
// the first byte past it) or every element (valid: nothing). A check of the start address
// alone passes both.
#include "catalogue_scene.h"
#include "trace_files.h"
#include "trace_script.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <ostream>
#include <string>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

constexpr uint64_t kSda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
constexpr uint64_t kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
constexpr uint64_t kInput = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
constexpr uint64_t kAsStorage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;

// Both arrays live in memory of their own, away from the catalogue's layout.
constexpr uint64_t kRangeBase = 0x30000000;
constexpr uint64_t kWide = 0x1000;  // the large buffer's size

std::string temp_path(const std::string& name) { return temp_trace_path("usage_range", name); }

struct RangeCase {
    const char* name;
    const char* vuid;
    uint64_t wide_usage;   // the large buffer: lacks the rule's usage
    uint64_t alias_usage;  // the alias over its start: has it
    uint64_t element;      // bytes of one element of the array
    bool infos;            // srcInfosArray (12305) or dstAddressesArray (12307)
};

const RangeCase kCases[] = {
    {"InfosRangeLeavesTheBufferWithBuildInputUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12305",
     kSda | kStorage | kAsStorage, kSda | kInput, sizeof(TriangleInfo), true},
    {"AddressesRangeLeavesTheBufferWithStorageUsage",
     "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12307",
     kSda | kStorage | kInput, kSda | kAsStorage, 8, false},
};

void PrintTo(const RangeCase& c, std::ostream* os) { *os << c.name; }

class UsageRange : public ::testing::TestWithParam<RangeCase> {};

// Writes the twin; returns the command index of the build.
uint32_t write_twin(const RangeCase& rc, bool broken, const std::string& path) {
    TraceScript t(path, device());
    add_buffers(t);
    t.buffer(0xc001, kRangeBase, kWide, rc.wide_usage, 0x2003, 0);
    // The alias is bound after the large buffer, so the image's region is the large one's.
    t.buffer(0xc002, kRangeBase, broken ? rc.element : kDefaultOps * rc.element, rc.alias_usage,
             0x2003, 0);
    ClusterCommand c = triangle_clusters(Destinations::kImplicit);
    if (rc.infos)
        c.info.srcInfosArray.deviceAddress = c.infos_address = kRangeBase;
    else
        c.info.dstAddressesArray.deviceAddress = kRangeBase;
    const uint32_t at = c.emit(t);
    t.finish();
    return at;
}

TEST_P(UsageRange, BrokenTwinNamesTheFirstByteOutsideTheUsage) {
    const RangeCase& rc = GetParam();
    const std::string path = temp_path(std::string(rc.name) + "_broken.clt");
    const uint32_t command = write_twin(rc, true, path);
    const replay::ReplayReport r = replay_file(path);
    std::remove(path.c_str());
    ASSERT_EQ(r.findings.size(), 1u) << replay::format_text(r);
    const replay::ReplayFinding& f = r.findings[0];
    EXPECT_EQ(f.rule, rc.vuid);
    EXPECT_EQ(f.where.command, command);
    EXPECT_EQ(f.op_index, -1);
    // Element 1 begins where the alias ends: its first byte is the first without the usage.
    EXPECT_EQ(f.address, kRangeBase + rc.element) << f.message;
    EXPECT_TRUE(r.hazards.empty()) << replay::format_text(r);
}

TEST_P(UsageRange, ValidTwinIsClean) {
    const RangeCase& rc = GetParam();
    const std::string path = temp_path(std::string(rc.name) + "_valid.clt");
    write_twin(rc, false, path);
    const replay::ReplayReport r = replay_file(path);
    std::remove(path.c_str());
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
}

INSTANTIATE_TEST_SUITE_P(Replay, UsageRange, ::testing::ValuesIn(kCases),
                         [](const ::testing::TestParamInfo<RangeCase>& info) {
                             return std::string(info.param.name);
                         });

// Two adjacent buffers both with the usage serve one range between them: every byte is
// covered, so a range crossing from one buffer into the next is no finding.
TEST(UsageRangeAdjacent, RangeOverTwoBuffersWithTheUsageIsClean) {
    const std::string path = temp_path("adjacent.clt");
    {
        TraceScript t(path, device());
        add_buffers(t);
        t.buffer(0xc001, kRangeBase, kWide, kSda | kStorage, 0x2003, 0);  // neither usage
        t.buffer(0xc002, kRangeBase, 8, kSda | kAsStorage, 0x2003, 0);
        t.buffer(0xc003, kRangeBase + 8, 8, kSda | kAsStorage, 0x2003, 8);
        ClusterCommand c = triangle_clusters(Destinations::kImplicit);
        c.info.dstAddressesArray.deviceAddress = kRangeBase;
        c.emit(t);
        t.finish();
    }
    const replay::ReplayReport r = replay_file(path);
    std::remove(path.c_str());
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
}

}  // namespace
