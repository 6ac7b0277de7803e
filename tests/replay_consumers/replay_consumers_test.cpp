// SPDX-License-Identifier: Apache-2.0
// Rays and ray queries in the synchronization model, on hand-written VK_NV_ray_tracing traces:
// a consumer reads its top level and every bottom level the top level's last build named, so a
// pool rebuilt while an earlier frame's rays are pending is a WRITE-AFTER-READ naming both
// frames and the fence wait, rays before the top level's barrier are a READ-AFTER-WRITE, and a
// structure destroyed while rays may still read it is a finding.
#include "consumer_trace.h"
#include "trace_files.h"

#include <clastrace/replay/replayer.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <string>
#include <vector>

namespace clastrace::consumertest {
namespace {

using replay::HazardClass;
using replay::HazardReport;
using replay::ReplayReport;

constexpr uint64_t kSetupFence = 0xF0, kFrame1Fence = 0xF1, kFrame2Fence = 0xF2;

std::string temp_path(const std::string& name) {
    return test::temp_trace_path("replay_consumers", name);
}

std::vector<HazardReport> of_class(const ReplayReport& r, HazardClass c) {
    std::vector<HazardReport> out;
    for (const HazardReport& h : r.hazards)
        if (h.hazard == c) out.push_back(h);
    return out;
}

std::string replay_hex(uint64_t v) {
    char text[24];
    std::snprintf(text, sizeof text, "0x%llx", static_cast<unsigned long long>(v));
    return text;
}

std::string all_hazards(const ReplayReport& r) {
    std::string s;
    for (const HazardReport& h : r.hazards) s += h.format() + "\n";
    for (const auto& f : r.findings) s += f.rule + ": " + f.message + "\n";
    return s;
}

struct Pool {
    ConsumerTrace::Object blas[2];
    ConsumerTrace::Object tlas;
};

// Frame 0: the pool's two bottom levels and the top level over them, made visible to rays,
// submitted with kSetupFence and waited for.
Pool built_pool(ConsumerTrace& t) {
    Pool p{{t.bottom_level(), t.bottom_level()}, {}};
    p.tlas = t.top_level(2);
    t.build_bottom(p.blas[0]);
    t.build_bottom(p.blas[1]);
    t.barrier(kBuildStages, kStructureWrite, kBuildStages | kRayStages, kStructureRead);
    t.build_top(p.tlas, {p.blas[0], p.blas[1]});
    t.barrier(kBuildStages, kStructureWrite, kRayStages, kStructureRead);
    t.submit(kSetupFence);
    t.wait(kSetupFence);
    return p;
}

// Frame 0 (built_pool), then frame 1: rays over the top level, submitted with kFrame1Fence, not
// waited for.
Pool setup_and_rays(ConsumerTrace& t) {
    Pool p = built_pool(t);
    t.present(0);
    t.trace_rays(p.tlas);
    t.submit(kFrame1Fence);
    t.present(1);
    return p;
}

// `twice`: frame 2 rebuilds the BLAS a second time with no barrier between the builds (a
// WRITE-AFTER-WRITE that owes nothing to the consumers).
ReplayReport pool_rebuilt_in_frame_2(const std::string& name, bool wait_for_frame_1,
                                     replay::ReplayOptions options = {}, bool twice = false) {
    const std::string path = temp_path(name);
    {
        ConsumerTrace t(path);
        Pool p = setup_and_rays(t);
        if (wait_for_frame_1) t.wait(kFrame1Fence);
        t.build_bottom(p.blas[0]);  // the single-buffered pool: frame 2 rebuilds frame 1's BLAS
        if (twice) t.build_bottom(p.blas[0]);
        t.submit(kFrame2Fence);
        t.wait(kFrame2Fence);
        t.present(2);
        t.finish();
    }
    ReplayReport r = test::replay_file(path, options);
    test::discard_trace(path);
    return r;
}

TEST(ReplayConsumers, PoolRebuiltWhileEarlierFramesRaysArePendingIsOneWriteAfterRead) {
    const ReplayReport r = pool_rebuilt_in_frame_2("pool_war.clt", false);
    const auto war = of_class(r, HazardClass::kWriteAfterRead);
    ASSERT_EQ(war.size(), 1u) << all_hazards(r);
    EXPECT_EQ(r.hazards.size(), 1u) << all_hazards(r);
    const HazardReport& h = war[0];
    EXPECT_STREQ(h.prior.command.name, "vkCmdTraceRaysKHR");
    EXPECT_STREQ(h.later.command.name, "vkCmdBuildAccelerationStructureNV");
    EXPECT_EQ(h.prior.frame, 1u);
    EXPECT_EQ(h.later.frame, 2u);
    EXPECT_EQ(h.prior.stage, kRayStages);
    EXPECT_EQ(h.prior.access, kStructureRead);
    // Reached through the top level: the rays bind only the top level.
    EXPECT_NE(h.prior.field.find("top level 0xa5002 > instance 0: bottom level 0xa5000"),
              std::string::npos)
        << h.prior.field;
    const std::string message = h.format();
    EXPECT_NE(message.find("frame 1"), std::string::npos) << message;
    EXPECT_NE(message.find("frame 2"), std::string::npos) << message;
    EXPECT_NE(message.find("vkWaitForFences"), std::string::npos) << message;
    EXPECT_NE(message.find("double-buffer the pool"), std::string::npos) << message;
    EXPECT_NE(message.find("SYNC-HAZARD-WRITE-AFTER-READ"), std::string::npos) << message;
}

// ReplayOptions::check_consumers = false (the consumer bench's peer): the rays' reads leave the
// hazard model, the builds stay in it and still replay.
TEST(ReplayConsumers, ConsumersOffDropsTheRaysReadsButKeepsTheBuildsHazards) {
    replay::ReplayOptions off;
    off.check_consumers = false;
    const ReplayReport on_report = pool_rebuilt_in_frame_2("consumers_on.clt", false, {}, true);
    const ReplayReport off_report = pool_rebuilt_in_frame_2("consumers_off.clt", false, off, true);
    EXPECT_EQ(of_class(on_report, HazardClass::kWriteAfterRead).size(), 1u)
        << all_hazards(on_report);
    EXPECT_TRUE(of_class(off_report, HazardClass::kWriteAfterRead).empty())
        << all_hazards(off_report);
    const auto waw = of_class(off_report, HazardClass::kWriteAfterWrite);
    ASSERT_FALSE(waw.empty()) << all_hazards(off_report);
    EXPECT_STREQ(waw[0].prior.command.name, "vkCmdBuildAccelerationStructureNV");
    EXPECT_STREQ(waw[0].later.command.name, "vkCmdBuildAccelerationStructureNV");
    EXPECT_EQ(off_report.counts.nv_builds, on_report.counts.nv_builds);
    EXPECT_EQ(off_report.counts.nv_builds, 5u);
    EXPECT_LT(off_report.counts.accesses, on_report.counts.accesses);
}

TEST(ReplayConsumers, PoolRebuiltAfterTheFenceWaitIsClean) {
    const ReplayReport r = pool_rebuilt_in_frame_2("pool_waited.clt", true);
    EXPECT_TRUE(r.hazards.empty()) << all_hazards(r);
    EXPECT_TRUE(r.findings.empty()) << all_hazards(r);
}

// Rays recorded after the top level's build with no barrier between them.
ReplayReport rays_after_build(const std::string& name, bool barrier, int consumer) {
    const std::string path = temp_path(name);
    {
        ConsumerTrace t(path);
        ConsumerTrace::Object blas = t.bottom_level(), tlas = t.top_level(1);
        t.build_bottom(blas);
        t.barrier(kBuildStages, kStructureWrite,
                  kBuildStages | kRayStages | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT |
                      VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT,
                  kStructureRead);
        t.build_top(tlas, {blas});
        const uint64_t stages = consumer == 0   ? kRayStages
                                : consumer == 1 ? VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT
                                                : VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT;
        if (barrier) t.barrier(kBuildStages, kStructureWrite, stages, kStructureRead);
        if (consumer == 0) t.trace_rays(tlas);
        if (consumer == 1) t.ray_query_dispatch(tlas);
        if (consumer == 2) t.ray_query_draw(tlas, stages);
        t.submit(kSetupFence);
        t.wait(kSetupFence);
        t.finish();
    }
    ReplayReport r = test::replay_file(path);
    test::discard_trace(path);
    return r;
}

TEST(ReplayConsumers, RaysBeforeTheTopLevelsBarrierAreReadAfterWrite) {
    const ReplayReport r = rays_after_build("rays_raw.clt", false, 0);
    const auto raw = of_class(r, HazardClass::kReadAfterWrite);
    ASSERT_EQ(raw.size(), 1u) << all_hazards(r);
    EXPECT_STREQ(raw[0].later.command.name, "vkCmdTraceRaysKHR");
    EXPECT_STREQ(raw[0].prior.command.name, "vkCmdBuildAccelerationStructureNV");
    EXPECT_NE(raw[0].later.field.find("top level 0xa5001"), std::string::npos);
    EXPECT_EQ(raw[0].later.field.find("instance"), std::string::npos) << raw[0].later.field;
    EXPECT_EQ(raw[0].fix.dst_stages & kRayStages, kRayStages);
    EXPECT_EQ(raw[0].fix.dst_access & kStructureRead, kStructureRead);
    EXPECT_FALSE(raw[0].prior.frame);  // a trace without presents has no frames
    EXPECT_TRUE(rays_after_build("rays_ok.clt", true, 0).hazards.empty());
}

TEST(ReplayConsumers, RayQueryDispatchesAndDrawsReadAtTheirShaderStages) {
    const ReplayReport dispatch = rays_after_build("query_raw.clt", false, 1);
    const auto d = of_class(dispatch, HazardClass::kReadAfterWrite);
    ASSERT_EQ(d.size(), 1u) << all_hazards(dispatch);
    EXPECT_STREQ(d[0].later.command.name, "vkCmdDispatch");
    EXPECT_EQ(d[0].later.stage, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT);
    // The dispatch names the top level by its address (the NV handle) only.
    EXPECT_NE(d[0].later.field.find("top level 0xa5001"), std::string::npos);
    const ReplayReport draw = rays_after_build("draw_raw.clt", false, 2);
    const auto g = of_class(draw, HazardClass::kReadAfterWrite);
    ASSERT_EQ(g.size(), 1u) << all_hazards(draw);
    EXPECT_STREQ(g[0].later.command.name, "vkCmdDraw");
    EXPECT_EQ(g[0].later.stage, VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT);
    EXPECT_TRUE(rays_after_build("query_ok.clt", true, 1).hazards.empty());
    EXPECT_TRUE(rays_after_build("draw_ok.clt", true, 2).hazards.empty());
}

// A dispatch that found the top level's address in its push constants (source 3) and in a
// buffer it binds (source 4), read before the build's barrier: each read-after-write names
// where the address was, the byte offset kept in array_element and, for the buffer, its set and
// binding.
TEST(ReplayConsumers, AddressesFoundInPushConstantsAndBuffersNameWhereTheyWere) {
    const std::string path = temp_path("found_addresses.clt");
    {
        ConsumerTrace t(path);
        ConsumerTrace::Object blas = t.bottom_level(), tlas = t.top_level(1);
        t.build_bottom(blas);
        // The bottom level is made visible to the dispatches, the top level is not.
        t.barrier(kBuildStages, kStructureWrite,
                  kBuildStages | VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, kStructureRead);
        t.build_top(tlas, {blas});
        const uint64_t address = tlas.driver_handle;
        t.ray_query_dispatch({fbs::AccelerationStructureBinding(0, 0, 8, 3, 0, address)});
        t.ray_query_dispatch({fbs::AccelerationStructureBinding(1, 2, 24, 4, 0, address)});
        t.submit(kSetupFence);
        t.wait(kSetupFence);
        t.finish();
    }
    const ReplayReport r = test::replay_file(path);
    test::discard_trace(path);
    const auto raw = of_class(r, HazardClass::kReadAfterWrite);
    ASSERT_EQ(raw.size(), 2u) << all_hazards(r);
    EXPECT_NE(raw[0].later.field.find("(address at byte 8 of the push constants)"),
              std::string::npos)
        << raw[0].later.field;
    EXPECT_NE(raw[1].later.field.find("(address at byte 24 of the buffer at set 1, binding 2)"),
              std::string::npos)
        << raw[1].later.field;
    EXPECT_NE(raw[1].format().find("set 1, binding 2"), std::string::npos) << raw[1].format();
}

// The bottom level rebuilt in the rays' own command buffer with no barrier: the rays bind only
// the top level, yet the rebuild overwrites what they read.
TEST(ReplayConsumers, BottomLevelRebuiltAfterRaysInOneCommandBufferNeedsABarrier) {
    const std::string path = temp_path("same_cb.clt");
    {
        ConsumerTrace t(path);
        ConsumerTrace::Object blas = t.bottom_level(), tlas = t.top_level(1);
        t.build_bottom(blas);
        t.barrier(kBuildStages, kStructureWrite, kBuildStages | kRayStages, kStructureRead);
        t.build_top(tlas, {blas});
        // Orders the top level's build (which reads the bottom level) before the rebuild too.
        t.barrier(kBuildStages, kStructureWrite, kRayStages | kBuildStages, kStructureRead);
        t.trace_rays(tlas);
        t.build_bottom(blas);
        t.submit(kSetupFence);
        t.wait(kSetupFence);
        t.finish();
    }
    const ReplayReport r = test::replay_file(path);
    test::discard_trace(path);
    const auto war = of_class(r, HazardClass::kWriteAfterRead);
    ASSERT_EQ(war.size(), 1u) << all_hazards(r);
    EXPECT_NE(war[0].prior.field.find("> instance 0: bottom level 0xa5000"), std::string::npos);
    EXPECT_EQ(war[0].fix.kind, replay::FixKind::kPipelineBarrier);
    EXPECT_EQ(war[0].fix.src_stages & kRayStages, kRayStages);
    EXPECT_TRUE(war[0].advice.empty()) << war[0].advice;  // one submission: the barrier is all
}

ReplayReport destroyed_in_frame_2(const std::string& name, bool wait_for_frame_1) {
    const std::string path = temp_path(name);
    {
        ConsumerTrace t(path);
        Pool p = setup_and_rays(t);
        if (wait_for_frame_1) t.wait(kFrame1Fence);
        t.destroy(p.blas[1]);
        t.finish();
    }
    ReplayReport r = test::replay_file(path);
    test::discard_trace(path);
    return r;
}

TEST(ReplayConsumers, BottomLevelDestroyedWhileRaysMayReadItIsAFinding) {
    const ReplayReport r = destroyed_in_frame_2("destroy.clt", false);
    ASSERT_EQ(r.findings.size(), 1u) << all_hazards(r);
    const auto& f = r.findings[0];
    EXPECT_EQ(f.rule, "VUID-vkDestroyAccelerationStructureNV-accelerationStructure-03752");
    EXPECT_NE(f.message.find("acceleration structure 0xa5001"), std::string::npos) << f.message;
    EXPECT_NE(f.message.find("vkCmdTraceRaysKHR"), std::string::npos) << f.message;
    EXPECT_NE(f.message.find("frame 1"), std::string::npos) << f.message;
    EXPECT_NE(f.message.find("top level 0xa5002 > instance 1"), std::string::npos) << f.message;
    EXPECT_TRUE(destroyed_in_frame_2("destroy_waited.clt", true).findings.empty());
}

// A structure destroyed while its own build is pending is in use too (03752's "refer to"):
// the finding names the build and the write; destroyed after the fence wait, nothing.
ReplayReport destroyed_while_building(const std::string& name, bool wait_first) {
    const std::string path = temp_path(name);
    {
        ConsumerTrace t(path);
        ConsumerTrace::Object blas = t.bottom_level();
        t.build_bottom(blas);
        t.submit(kSetupFence);
        if (wait_first) t.wait(kSetupFence);
        t.destroy(blas);
        t.finish();
    }
    ReplayReport r = test::replay_file(path);
    test::discard_trace(path);
    return r;
}

TEST(ReplayConsumers, BottomLevelDestroyedWhileItsBuildIsPendingIsAFinding) {
    const ReplayReport r = destroyed_while_building("destroy_building.clt", false);
    ASSERT_EQ(r.findings.size(), 1u) << all_hazards(r);
    const auto& f = r.findings[0];
    EXPECT_EQ(f.rule, "VUID-vkDestroyAccelerationStructureNV-accelerationStructure-03752");
    EXPECT_NE(f.message.find("vkCmdBuildAccelerationStructureNV (queue 0, submit 0, cb 0, cmd 0), "
                             "which writes it"),
              std::string::npos)
        << f.message;
    // Its own place, a call of the host's: the next submission's index and the next command's
    // --ops number.
    EXPECT_TRUE(
        f.format().starts_with("VUID-vkDestroyAccelerationStructureNV-accelerationStructure-"
                               "03752: vkDestroyAccelerationStructureNV (host, submit 1) "
                               "[#1]: "))
        << f.format();
    EXPECT_TRUE(destroyed_while_building("destroy_built.clt", true).findings.empty());
}

// Rays and a ray-query dispatch, in two command buffers of one submission (or in two
// secondaries of one vkCmdExecuteCommands), both read a bottom level destroyed before the fence
// wait: two pending commands at the same command index, two findings, each naming its own
// place. (Two readers at one stage would be one: the model keeps the latest read per queue and
// stage.)
ReplayReport destroyed_under_two_readers(const std::string& name, bool secondaries) {
    const std::string path = temp_path(name);
    {
        ConsumerTrace t(path);
        Pool p = built_pool(t);
        if (secondaries) {
            std::vector<uint64_t> listed;
            t.begin_secondary();
            t.trace_rays(p.tlas);
            listed.push_back(t.end_secondary());
            t.begin_secondary();
            t.ray_query_dispatch(p.tlas);
            listed.push_back(t.end_secondary());
            t.execute_commands(listed);
        } else {
            t.trace_rays(p.tlas);
            t.next_command_buffer();
            t.ray_query_dispatch(p.tlas);
        }
        t.submit(kFrame1Fence);
        t.destroy(p.blas[1]);
        t.finish();
    }
    ReplayReport r = test::replay_file(path);
    test::discard_trace(path);
    return r;
}

int count_naming(const ReplayReport& r, const std::string& place) {
    int n = 0;
    for (const auto& f : r.findings) n += f.message.find(place) != std::string::npos;
    return n;
}

TEST(ReplayConsumers, DestroyedUnderTwoCommandBuffersOfOneSubmissionIsTwoFindings) {
    const ReplayReport r = destroyed_under_two_readers("destroy_two_cbs.clt", false);
    ASSERT_EQ(r.findings.size(), 2u) << all_hazards(r);
    for (const auto& f : r.findings)
        EXPECT_EQ(f.rule, "VUID-vkDestroyAccelerationStructureNV-accelerationStructure-03752");
    for (const char* place : {"submit 1, cb 0, cmd 0)", "submit 1, cb 1, cmd 0)"})
        EXPECT_EQ(count_naming(r, place), 1) << place << "\n" << all_hazards(r);
}

TEST(ReplayConsumers, DestroyedUnderTwoSecondariesOfOneExecuteIsTwoFindings) {
    const ReplayReport r = destroyed_under_two_readers("destroy_two_secondaries.clt", true);
    ASSERT_EQ(r.findings.size(), 2u) << all_hazards(r);
    for (const char* place :
         {"cmd 0 > secondary 0 (0xd000), cmd 0)", "cmd 0 > secondary 1 (0xd001), cmd 0)"})
        EXPECT_EQ(count_naming(r, place), 1) << place << "\n" << all_hazards(r);
}

// A KHR top level names its bottom levels by device address: overwriting a bottom level's
// buffer after rays that bind only the top level's address is a WRITE-AFTER-READ, whether the
// instances were packed or given as an array of pointers.
TEST(ReplayConsumers, KhrTopLevelReachesItsBottomLevelsByAddress) {
    for (const bool pointers : {false, true}) {
        const std::string path = temp_path(pointers ? "khr_pointers.clt" : "khr_packed.clt");
        uint64_t second_buffer = 0;
        ConsumerTrace::Object tlas, second;
        {
            ConsumerTrace t(path);
            ConsumerTrace::Object first = t.khr_structure(false);
            second = t.khr_structure(false, &second_buffer);
            tlas = t.khr_structure(true);
            t.build_khr_top(tlas, {first, second}, pointers);
            t.barrier(kBuildStages, kStructureWrite, kRayStages, kStructureRead);
            t.trace_rays_at(tlas.driver_handle);
            t.fill(second_buffer);
            t.submit(kSetupFence);
            t.wait(kSetupFence);
            t.finish();
        }
        const ReplayReport r = test::replay_file(path);
        test::discard_trace(path);
        const auto war = of_class(r, HazardClass::kWriteAfterRead);
        ASSERT_EQ(war.size(), 1u) << all_hazards(r);
        EXPECT_STREQ(war[0].later.command.name, "vkCmdFillBuffer");
        // The pointers list the instances in reverse: the second bottom level is instance 0.
        const std::string expected = "top level " + replay_hex(tlas.handle) + " > instance " +
                                     (pointers ? "0" : "1") + ": bottom level " +
                                     replay_hex(second.handle);
        EXPECT_NE(war[0].prior.field.find(expected), std::string::npos)
            << war[0].prior.field << " (arrayOfPointers " << pointers << ")";
    }
}

}  // namespace
}  // namespace clastrace::consumertest
