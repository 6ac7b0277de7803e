// SPDX-License-Identifier: Apache-2.0
// Driver-sized ranges: a cluster command's scratch spans the buildScratchSize, and its implicit
// destinations the accelerationStructureSize, that the trace's
// vkGetClusterAccelerationStructureBuildSizesNV query answered for its input (else the
// engine's worst case, said as assumed), not the bytes the engine happened to use. Each
// broken scene has a correct twin (a barrier, or ranges disjoint beyond the answered sizes).
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

namespace clastrace::test::catalogue {
namespace {

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;

// The driver's answers: larger than the engine's 16 bytes per op (64 for 4 ops, 256 worst
// case for 16) and than the bytes two quads pack into.
constexpr uint64_t kQueriedScratch = 1024;
constexpr uint64_t kQueriedImplicit = 0x4000;

std::string path_of(const char* name) { return temp_trace_path("replay_driver_sizes", name); }

// Triangle clusters sized for 16 ops (maxAccelerationStructureCount) with 4 in memory
// (srcInfosCount), as an application sizes its buffers once for its largest batch.
ClusterCommand sixteen_sized_build() {
    ClusterCommand c = triangle_clusters(Destinations::kImplicit, 4);
    c.info.input.maxAccelerationStructureCount = 16;
    c.info.srcInfosCount = kCount;
    c.inputs.push_back({kCount, bytes_of(std::vector<uint32_t>{4})});
    return c;
}

// The build-size query for `c`'s input, answered with the driver's sizes.
void query(TraceScript& t, ClusterCommand& c, uint64_t implicit_size, uint64_t scratch_size) {
    VkClusterAccelerationStructureInputInfoNV input = c.info.input;
    input.opInput.pTriangleClusters = &c.triangles;
    t.query_build_sizes(input, implicit_size, scratch_size);
}

// The second build: its own destinations and arrays, its scratch at `scratch`.
ClusterCommand second_build(uint64_t scratch) {
    ClusterCommand c = sixteen_sized_build();
    c.info.scratchData = scratch;
    c.info.dstImplicitData = kDst2;
    c.info.dstAddressesArray.deviceAddress = kOut + 0x400;
    c.info.dstSizesArray.deviceAddress = kSizes + 0x400;
    return c;
}

enum class Twin { kBroken, kBarrier, kBeyondAnswer };

replay::ReplayReport shared_scratch(const char* name, Twin twin, bool with_query) {
    return replay_catalogue_scene(path_of(name), [&](TraceScript& t) {
        ClusterCommand first = sixteen_sized_build();
        if (with_query) query(t, first, kQueriedImplicit, kQueriedScratch);
        first.emit(t);
        if (twin == Twin::kBarrier) t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        // Inside the answered scratch (1024 bytes queried, 256 the engine's worst case) and
        // past the 64 bytes the engine writes for 4 ops.
        const uint64_t inside = with_query ? 512 : 128;
        const uint64_t beyond = with_query ? kQueriedScratch : 256;
        second_build(kScratch + (twin == Twin::kBeyondAnswer ? beyond : inside)).emit(t);
    });
}

TEST(DriverSizes, ScratchInsideQueriedSizeIsAHazard) {
    const replay::ReplayReport r = shared_scratch("scratch_broken", Twin::kBroken, true);
    ASSERT_EQ(r.hazards.size(), 1u);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterWrite);
    EXPECT_EQ(h.overlap.begin, kScratch + 512);
    EXPECT_EQ(h.overlap.end, kScratch + kQueriedScratch);
    const std::string message = h.format();
    EXPECT_NE(message.find("1024-byte buildScratchSize answered by the trace's "
                           "vkGetClusterAccelerationStructureBuildSizesNV query"),
              std::string::npos)
        << message;
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].message;
}

TEST(DriverSizes, ScratchTwinsAreClean) {
    for (Twin twin : {Twin::kBarrier, Twin::kBeyondAnswer}) {
        const replay::ReplayReport r = shared_scratch("scratch_twin", twin, true);
        EXPECT_TRUE(r.clean()) << (r.hazards.empty() ? r.findings[0].message
                                                     : r.hazards[0].format());
    }
}

// No query in the trace: the engine's worst case (16 bytes for each of 16 ops) is assumed,
// and the message says so.
TEST(DriverSizes, ScratchWithoutQueryAssumesTheEngineWorstCase) {
    const replay::ReplayReport r = shared_scratch("scratch_assumed", Twin::kBroken, false);
    ASSERT_EQ(r.hazards.size(), 1u);
    EXPECT_EQ(r.hazards[0].overlap.end, kScratch + 256);
    const std::string message = r.hazards[0].format();
    EXPECT_NE(message.find("256-byte buildScratchSize assumed (the engine's worst case"),
              std::string::npos)
        << message;
    ASSERT_FALSE(r.sizes.empty());
    EXPECT_FALSE(r.sizes[0].spans_queried);
    EXPECT_EQ(r.sizes[0].scratch_span, 256u);
    const replay::ReplayReport twin = shared_scratch("scratch_assumed", Twin::kBeyondAnswer, false);
    EXPECT_TRUE(twin.clean()) << (twin.hazards.empty() ? twin.findings[0].message
                                                       : twin.hazards[0].format());
}

replay::ReplayReport shared_implicit_region(const char* name, Twin twin) {
    return replay_catalogue_scene(path_of(name), [&](TraceScript& t) {
        ClusterCommand first = triangle_clusters(Destinations::kImplicit);
        query(t, first, kQueriedImplicit, kQueriedScratch);
        first.emit(t);
        if (twin == Twin::kBarrier) t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        ClusterCommand second = triangle_clusters(Destinations::kImplicit);
        second.info.scratchData = kScratch2;
        // Two quads pack into far less than 0x2000 bytes: past them, inside the answer.
        second.info.dstImplicitData =
            kDst + (twin == Twin::kBeyondAnswer ? kQueriedImplicit : 0x2000);
        second.info.dstAddressesArray.deviceAddress = kOut + 0x400;
        second.info.dstSizesArray.deviceAddress = kSizes + 0x400;
        second.emit(t);
    });
}

// The second build writes its objects and the rest of its own region inside the first's
// region: one hazard for its packed objects, one for its unpacked bytes, both against the
// first build's region named with its queried size.
TEST(DriverSizes, ImplicitDataInsideQueriedRegionIsAHazard) {
    const replay::ReplayReport r = shared_implicit_region("implicit_broken", Twin::kBroken);
    ASSERT_EQ(r.hazards.size(), 2u);
    uint64_t first_byte = UINT64_MAX;
    bool packed_object = false;
    for (const replay::HazardReport& h : r.hazards) {
        EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterWrite);
        first_byte = std::min(first_byte, h.overlap.begin);
        EXPECT_NE(h.prior.field.find("dstImplicitData (the 16384-byte implicit region answered "
                                     "by the trace's"),
                  std::string::npos)
            << h.prior.field;
        EXPECT_NE(h.format().find("16384-byte implicit region"), std::string::npos) << h.format();
        packed_object |= h.later.field.starts_with("dstImplicitData[op ");
    }
    EXPECT_EQ(first_byte, kDst + 0x2000);
    EXPECT_TRUE(packed_object);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].message;
}

TEST(DriverSizes, ImplicitTwinsAreClean) {
    for (Twin twin : {Twin::kBarrier, Twin::kBeyondAnswer}) {
        const replay::ReplayReport r = shared_implicit_region("implicit_twin", twin);
        EXPECT_TRUE(r.clean()) << (r.hazards.empty() ? r.findings[0].message
                                                     : r.hazards[0].format());
    }
}

// Explicit destinations span dstSizesArray's entries (what the driver reads) or, without it,
// the answered per-object maximum. The second build's destination lies past the engine's
// object, inside that span (broken) or just beyond it (twin).
replay::ReplayReport explicit_neighbour(const char* name, Twin twin, bool sizes_array) {
    constexpr uint64_t kSizesEntry = 0x600, kQueriedObject = 0x800;
    return replay_catalogue_scene(path_of(name), [&](TraceScript& t) {
        ClusterCommand first = triangle_clusters(Destinations::kExplicit);
        query(t, first, kQueriedObject, kQueriedScratch);
        if (sizes_array) {
            first.info.dstSizesArray = {kSizes, 4, 8};
            first.inputs.push_back(
                {kSizes, bytes_of(std::vector<uint32_t>{kSizesEntry, kSizesEntry})});
        }
        first.emit(t);
        if (twin == Twin::kBarrier) t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        const uint64_t span = sizes_array ? kSizesEntry : kQueriedObject;
        ClusterCommand second = triangle_clusters(Destinations::kExplicit);
        second.info.scratchData = kScratch2;
        second.info.dstAddressesArray.deviceAddress = kOut + 0x400;
        second.inputs.back() = {kOut + 0x400,
                                bytes_of(std::vector<uint64_t>{
                                    kDst + (twin == Twin::kBeyondAnswer ? span : 0x500), kDst2})};
        second.emit(t);
    });
}

TEST(DriverSizes, ExplicitDestinationInsideDriverSpanIsAHazard) {
    for (bool sizes_array : {true, false}) {
        const replay::ReplayReport r =
            explicit_neighbour("explicit_broken", Twin::kBroken, sizes_array);
        ASSERT_EQ(r.hazards.size(), 1u) << "dstSizesArray " << sizes_array;
        const replay::HazardReport& h = r.hazards[0];
        EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterWrite);
        EXPECT_EQ(h.overlap.begin, kDst + 0x500);
        EXPECT_EQ(h.overlap.end, kDst + (sizes_array ? 0x600 : 0x800));
        EXPECT_NE(h.prior.field.find("*dstAddressesArray[0]"), std::string::npos) << h.prior.field;
        EXPECT_TRUE(r.findings.empty()) << r.findings[0].message;
        for (Twin twin : {Twin::kBarrier, Twin::kBeyondAnswer}) {
            const replay::ReplayReport clean =
                explicit_neighbour("explicit_twin", twin, sizes_array);
            EXPECT_TRUE(clean.clean())
                << (clean.hazards.empty() ? clean.findings[0].message : clean.hazards[0].format());
        }
    }
}

// 12300 against the queried size: 512 bytes of scratch hold the engine's 64 and its worst
// case of 256, not the 1024 the driver answered.
TEST(DriverSizes, ScratchSmallerThanQueriedSizeBreaks12300) {
    for (bool broken : {true, false}) {
        const replay::ReplayReport r =
            replay_catalogue_scene(path_of("scratch_12300"), [&](TraceScript& t) {
                ClusterCommand c = sixteen_sized_build();
                query(t, c, kQueriedImplicit, kQueriedScratch);
                c.info.scratchData = kScratch + 0x10000 - (broken ? 512 : kQueriedScratch);
                c.emit(t);
            });
        std::vector<std::string> rules;
        for (const replay::ReplayFinding& f : r.findings) rules.push_back(f.rule);
        if (!broken) {
            EXPECT_TRUE(rules.empty()) << rules[0];
            continue;
        }
        ASSERT_EQ(rules.size(), 1u);
        EXPECT_EQ(rules[0],
                  "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12300");
        EXPECT_NE(r.findings[0].message.find("less than the 1024-byte buildScratchSize answered"),
                  std::string::npos)
            << r.findings[0].message;
    }
}

// 12303 against the queried sizes: dstImplicitData placed past the engine's 64 bytes of
// scratch but inside the 1024 the driver may touch.
TEST(DriverSizes, ImplicitDataInsideQueriedScratchBreaks12303) {
    for (bool broken : {true, false}) {
        const replay::ReplayReport r =
            replay_catalogue_scene(path_of("implicit_12303"), [&](TraceScript& t) {
                ClusterCommand c = sixteen_sized_build();
                query(t, c, kQueriedImplicit, kQueriedScratch);
                c.info.dstImplicitData = kScratch + (broken ? 512 : kQueriedScratch);
                c.emit(t);
            });
        std::vector<std::string> rules;
        for (const replay::ReplayFinding& f : r.findings) rules.push_back(f.rule);
        if (!broken) {
            EXPECT_TRUE(rules.empty()) << rules[0];
            continue;
        }
        ASSERT_EQ(rules.size(), 1u);
        EXPECT_EQ(rules[0],
                  "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstImplicitData-12303");
    }
}

// A driver trace whose sizes differ from the engine's: the ranges follow the driver's.
TEST(DriverSizes, DriverTraceRangesFollowTheDriverSizes) {
    constexpr uint64_t kDriverScratch = 4096, kDriverImplicit = 0x8000;
    ScriptDevice driver = device();
    driver.driver_name = "stand-in vendor driver";
    for (bool broken : {true, false}) {
        const std::string path = path_of("driver_trace");
        {
            TraceScript t(path, driver);
            add_buffers(t);
            ClusterCommand first = sixteen_sized_build();
            query(t, first, kDriverImplicit, kDriverScratch);
            first.emit(t);
            // Inside the driver's 4096 bytes, past the engine's worst case of 256.
            ClusterCommand second = second_build(kScratch + (broken ? 2048 : kDriverScratch));
            // Inside the driver's implicit region, past the engine's worst case.
            second.info.dstImplicitData = kDst + (broken ? 0x6000 : kDriverImplicit);
            second.emit(t);
            t.finish();
        }
        const replay::ReplayReport r = replay_file(path);
        discard_trace(path);
        EXPECT_FALSE(r.engine_trace);
        ASSERT_EQ(r.sizes.size(), 2u);
        EXPECT_TRUE(r.sizes[0].spans_queried);
        EXPECT_EQ(r.sizes[0].scratch_span, kDriverScratch);
        EXPECT_EQ(r.sizes[0].destination_span, kDriverImplicit);
        if (!broken) {
            EXPECT_TRUE(r.clean())
                << (r.hazards.empty() ? r.findings[0].message : r.hazards[0].format());
            continue;
        }
        // The shared scratch, and the second's objects and unpacked bytes in the first's region.
        ASSERT_EQ(r.hazards.size(), 3u);
        int scratch = 0, region = 0;
        for (const replay::HazardReport& h : r.hazards) {
            scratch += h.prior.field.starts_with("scratchData (the 4096-byte buildScratchSize");
            region += h.prior.field.starts_with("dstImplicitData (the 32768-byte implicit region");
        }
        EXPECT_EQ(scratch, 1);
        EXPECT_EQ(region, 2);
    }
}

}  // namespace
}  // namespace clastrace::test::catalogue
