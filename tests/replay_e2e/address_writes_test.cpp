// SPDX-License-Identifier: Apache-2.0
// Cheap mode for GPU-written inputs: a dispatch whose pipeline may write through buffer device
// addresses is a possible writer of all device-address memory. A build reading its inputs with
// no barrier after it gets a POSSIBLE hazard, counted apart from certain ones; the barrier the
// report suggests makes it clean; a dispatch without the mark (bound storage buffers only) is
// not a writer of the build's inputs at all.
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <string>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;
using replay::HazardClass;

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kCompute = VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
constexpr uint64_t kStorageWrite = VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT;
constexpr uint64_t kInputReads = VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT |
                                 VK_ACCESS_2_SHADER_READ_BIT |
                                 VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;

std::string temp_path(const std::string& name) { return temp_trace_path("address_writes", name); }

std::vector<uint8_t> triangle_infos() {
    std::vector<TriangleInfo> infos{triangle_info(0), triangle_info(1)};
    return bytes_of(infos);
}

// The compute pass writes the src infos through an address (what the capture saw it write is
// its output), then the build reads them; `barrier` puts COMPUTE/STORAGE_WRITE -> BUILD between.
replay::ReplayReport infos_written_through_address(const std::string& name, bool barrier) {
    return replay_catalogue_scene(temp_path(name), [&](TraceScript& t) {
        t.dispatch_through_addresses({{kInfos, triangle_infos()}});
        if (barrier) t.barrier(kCompute, kStorageWrite, kBuild, kInputReads);
        triangle_clusters(Destinations::kImplicit).emit(t);
    });
}

TEST(AddressWrites, BuildAfterAddressWritingDispatchWithoutBarrierIsAPossibleHazard) {
    const replay::ReplayReport r = infos_written_through_address("no_barrier.clt", false);
    const std::string text = replay::format_text(r);
    ASSERT_FALSE(r.hazards.empty()) << text;
    for (const replay::HazardReport& h : r.hazards) {
        EXPECT_TRUE(h.possible()) << h.format();
        EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite) << h.format();
        EXPECT_STREQ(h.prior.command.name, "vkCmdDispatch");
        EXPECT_TRUE(h.prior.possible);
        EXPECT_EQ(h.prior.stage, kCompute);
        EXPECT_STREQ(h.later.command.name, "vkCmdBuildClusterAccelerationStructureIndirectNV");
        EXPECT_EQ(h.fix.src_stages, kCompute) << h.format();
        EXPECT_EQ(h.fix.dst_stages, kBuild) << h.format();
    }
    bool infos_named = false;
    for (const replay::HazardReport& h : r.hazards)
        // The infos themselves: not the vertex buffers they point at (srcInfosArray[k].vertexBuffer).
        if (h.later.field.rfind("srcInfosArray", 0) == 0 &&
            h.later.field.find('.') == std::string::npos) {
            infos_named = true;
            EXPECT_GE(h.overlap.begin, kInfos);
            EXPECT_LE(h.overlap.end, kInfos + triangle_infos().size());
            const std::string line = h.format();
            EXPECT_EQ(line.rfind("POSSIBLE-SYNC-HAZARD-READ-AFTER-WRITE: ", 0), 0u) << line;
            EXPECT_NE(line.find("Possible, not certain"), std::string::npos) << line;
        }
    EXPECT_TRUE(infos_named) << text;
    // Counted apart: the summary's rule and the JSON's counts.
    EXPECT_NE(text.find("POSSIBLE-SYNC-HAZARD-READ-AFTER-WRITE"), std::string::npos) << text;
    const nlohmann::json j = replay::to_json(r);
    EXPECT_EQ(j["hazards"]["possible"], r.hazards.size());
    EXPECT_EQ(j["hazards"]["certain"], 0u);
    EXPECT_EQ(j["hazards"]["hazards"][0]["possible"], true);
}

TEST(AddressWrites, TheSuggestedBarrierMakesItClean) {
    const replay::ReplayReport r = infos_written_through_address("barrier.clt", true);
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
}

// Possible writes meet reads only (docs/replay.md): a later write with no barrier after the
// dispatch is not reported, though it is a real WRITE-AFTER-WRITE when the shader did write
// those bytes (cheap mode's stated gap); so the build's own scratch and destination writes,
// outside the barrier's read scope, raise nothing either.
TEST(AddressWrites, ALaterWriteGetsNoPossibleWriteAfterWrite) {
    const replay::ReplayReport r =
        replay_catalogue_scene(temp_path("later_fill.clt"), [](TraceScript& t) {
            t.dispatch_through_addresses({{kInfos, triangle_infos()}});
            t.fill(kInfosBuffer, 0, 0x1000, 0);
        });
    EXPECT_TRUE(r.hazards.empty()) << replay::format_text(r);
}

// The other side is kept: a read before the dispatch with nothing ordering the dispatch after
// it is a possible WRITE-AFTER-READ (a build's src infos rewritten too early).
TEST(AddressWrites, AnEarlierReadIsAPossibleWriteAfterRead) {
    const replay::ReplayReport r =
        replay_catalogue_scene(temp_path("earlier_read.clt"), [](TraceScript& t) {
            triangle_clusters(Destinations::kImplicit).emit(t);
            t.dispatch_through_addresses();
        });
    ASSERT_FALSE(r.hazards.empty()) << replay::format_text(r);
    bool infos = false;
    for (const replay::HazardReport& h : r.hazards) {
        EXPECT_TRUE(h.possible()) << h.format();
        EXPECT_STREQ(h.later.command.name, "vkCmdDispatch");
        // Only reads: the build's scratch and destination writes meet no possible write.
        EXPECT_EQ(h.hazard, HazardClass::kWriteAfterRead) << h.format();
        if (h.prior.field == "srcInfosArray[*]") {  // the infos, not the buffers they name
            infos = true;
            EXPECT_EQ(h.overlap.begin, kInfos) << h.format();
        }
    }
    EXPECT_TRUE(infos) << replay::format_text(r);
}

// The possible write sits beside the bytes' certain write and hides nothing: a copy writes the
// infos, the dispatch runs unordered after it, and the barrier orders only the dispatch before
// the build; the copy-to-build READ-AFTER-WRITE is still found, certain.
TEST(AddressWrites, APossibleWriteDoesNotHideAnEarlierCertainWrite) {
    const replay::ReplayReport r =
        replay_catalogue_scene(temp_path("copy_then_dispatch.clt"), [](TraceScript& t) {
            const std::vector<uint8_t> infos = triangle_infos();
            t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});
            t.dispatch_through_addresses();
            t.barrier(kCompute, kStorageWrite, kBuild, kInputReads);
            triangle_clusters(Destinations::kImplicit).emit(t);
        });
    bool copy_to_build = false;
    for (const replay::HazardReport& h : r.hazards) {
        EXPECT_NE(std::string(h.prior.command.name), "vkCmdDispatch") << h.format();
        if (!h.possible() && h.hazard == HazardClass::kReadAfterWrite &&
            std::string(h.prior.command.name) == "vkCmdCopyBuffer" &&
            h.later.field == "srcInfosArray[*]")
            copy_to_build = true;
    }
    EXPECT_TRUE(copy_to_build) << replay::format_text(r);
}

// A certain hazard after the possible writer stays certain, and the two are counted apart.
TEST(AddressWrites, CertainHazardsAreCountedApartFromPossibleOnes) {
    const replay::ReplayReport r =
        replay_catalogue_scene(temp_path("both.clt"), [](TraceScript& t) {
            t.dispatch_through_addresses({{kInfos, triangle_infos()}});
            triangle_clusters(Destinations::kImplicit).emit(t);
            ClusterCommand second = triangle_clusters(Destinations::kImplicit);  // same scratch
            second.info.dstImplicitData = kDst2;
            second.info.dstAddressesArray.deviceAddress = kOut + 0x400;
            second.emit(t);
        });
    const std::string text = replay::format_text(r);
    uint64_t certain = 0, possible = 0;
    for (const replay::HazardReport& h : r.hazards) (h.possible() ? possible : certain) += 1;
    EXPECT_GE(possible, 1u) << text;
    ASSERT_GE(certain, 1u) << text;
    for (const replay::HazardReport& h : r.hazards)
        if (!h.possible()) {
            EXPECT_STREQ(h.prior.command.name, "vkCmdBuildClusterAccelerationStructureIndirectNV");
            EXPECT_EQ(h.format().rfind("SYNC-HAZARD-", 0), 0u) << h.format();
        }
    const nlohmann::json j = replay::to_json(r);
    EXPECT_EQ(j["hazards"]["certain"], certain);
    EXPECT_EQ(j["hazards"]["possible"], possible);
}

// Draws: a mesh pipeline whose mesh and fragment shaders use addresses is a possible writer at
// both stages; a barrier from the mesh stage alone leaves the fragment-shader write unordered
// (a source scope takes in the logically earlier stages, so the fragment stage alone would
// take the mesh stage in: the model keeps no separate access scope per stage).
constexpr uint64_t kMeshAndFragment =
    VK_PIPELINE_STAGE_2_MESH_SHADER_BIT_EXT | VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT;

replay::ReplayReport mesh_draw_then_build(const std::string& name, uint64_t barrier_stages) {
    return replay_catalogue_scene(temp_path(name), [&](TraceScript& t) {
        t.draw_through_addresses("vkCmdDrawMeshTasksEXT", kMeshAndFragment);
        if (barrier_stages) t.barrier(barrier_stages, kStorageWrite, kBuild, kInputReads);
        triangle_clusters(Destinations::kImplicit).emit(t);
    });
}

TEST(AddressWrites, MeshDrawWritingThroughAddressesIsAPossibleWriterAtItsShaderStages) {
    const replay::ReplayReport r = mesh_draw_then_build("mesh_draw.clt", 0);
    const std::string text = replay::format_text(r);
    ASSERT_FALSE(r.hazards.empty()) << text;
    for (const replay::HazardReport& h : r.hazards) {
        EXPECT_TRUE(h.possible()) << h.format();
        EXPECT_STREQ(h.prior.command.name, "vkCmdDrawMeshTasksEXT");
        EXPECT_EQ(h.prior.stage, kMeshAndFragment) << h.format();
        EXPECT_EQ(h.fix.src_stages, kMeshAndFragment) << h.format();  // the fix names both
    }
    EXPECT_NE(text.find("vkCmdDrawMeshTasksEXT"), std::string::npos) << text;
}

TEST(AddressWrites, ABarrierFromOneOfTheDrawsStagesLeavesTheOtherUnordered) {
    const replay::ReplayReport partial =
        mesh_draw_then_build("mesh_draw_mesh_barrier.clt", VK_PIPELINE_STAGE_2_MESH_SHADER_BIT_EXT);
    ASSERT_FALSE(partial.hazards.empty()) << replay::format_text(partial);
    for (const replay::HazardReport& h : partial.hazards) {
        EXPECT_TRUE(h.possible()) << h.format();
        EXPECT_EQ(h.prior.stage, kMeshAndFragment) << h.format();
        EXPECT_EQ(h.fix.src_stages, kMeshAndFragment) << h.format();  // the fix names both
    }
    const replay::ReplayReport both =
        mesh_draw_then_build("mesh_draw_both_barrier.clt",
                             VK_PIPELINE_STAGE_2_MESH_SHADER_BIT_EXT |
                                 VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT);
    EXPECT_TRUE(both.clean()) << replay::format_text(both);
}

}  // namespace

// Exact mode (CLASTRACE_DEVICE_ADDRESS_WRITES=exact): a DeviceAddressWrites record ahead of the
// QueueSubmit says which bytes the dispatch changed in that execution. Those are certain
// writes: the missing barrier is an ordinary hazard on exactly those bytes, and nothing else is
// taken as written.
replay::ReplayReport exact_infos_written(const std::string& name, bool barrier,
                                         uint64_t written_at) {
    return replay_catalogue_scene(temp_path(name), [&](TraceScript& t) {
        t.dispatch_through_addresses();
        t.exact_address_writes({{written_at, triangle_infos()}});
        if (barrier) t.barrier(kCompute, kStorageWrite, kBuild, kInputReads);
        triangle_clusters(Destinations::kImplicit).emit(t);
    });
}

TEST(AddressWrites, ExactWritesWithoutTheBarrierAreACertainHazardOnTheirBytes) {
    const replay::ReplayReport r = exact_infos_written("exact_no_barrier.clt", false, kInfos);
    const std::string text = replay::format_text(r);
    ASSERT_FALSE(r.hazards.empty()) << text;
    bool infos_named = false;
    for (const replay::HazardReport& h : r.hazards) {
        EXPECT_FALSE(h.possible()) << h.format();
        EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite) << h.format();
        EXPECT_STREQ(h.prior.command.name, "vkCmdDispatch");
        EXPECT_EQ(h.prior.stage, kCompute);
        EXPECT_EQ(h.prior.access, kStorageWrite);
        EXPECT_STREQ(h.later.command.name, "vkCmdBuildClusterAccelerationStructureIndirectNV");
        // Only the bytes the dispatch changed: the vertex reads are not touched.
        EXPECT_GE(h.overlap.begin, kInfos) << h.format();
        EXPECT_LE(h.overlap.end, kInfos + triangle_infos().size()) << h.format();
        if (h.later.field == "srcInfosArray[*]") {
            infos_named = true;
            EXPECT_EQ(h.format().rfind("SYNC-HAZARD-READ-AFTER-WRITE: ", 0), 0u) << h.format();
            EXPECT_EQ(h.fix.src_stages, kCompute) << h.format();
            EXPECT_EQ(h.fix.dst_stages, kBuild) << h.format();
        }
    }
    EXPECT_TRUE(infos_named) << text;
    const nlohmann::json j = replay::to_json(r);
    EXPECT_EQ(j["hazards"]["possible"], 0u);
    EXPECT_EQ(j["hazards"]["certain"], r.hazards.size());
}

TEST(AddressWrites, ExactWritesWithTheBarrierAreClean) {
    const replay::ReplayReport r = exact_infos_written("exact_barrier.clt", true, kInfos);
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
}

// The same marked dispatch whose writes landed where nothing reads: no report, where cheap mode
// (the same trace without the record) reports possible hazards on every later read.
TEST(AddressWrites, ExactWritesElsewhereRaiseNothing) {
    const replay::ReplayReport r = exact_infos_written("exact_elsewhere.clt", false, kStaging);
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
    const replay::ReplayReport cheap = infos_written_through_address("cheap_elsewhere.clt", false);
    EXPECT_FALSE(cheap.hazards.empty());
}
