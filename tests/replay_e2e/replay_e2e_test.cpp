// SPDX-License-Identifier: Apache-2.0
// End-to-end replay: traces written with the TraceWriter, replayed through the engine and
// the synchronization model. Each broken scene has a correctly synchronized/valid twin.
#include "scene_trace.h"
#include "trace_files.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sys/wait.h>

namespace {

using namespace clastrace;
using test::BuildCall;
using test::SceneBuffers;
using test::SceneTrace;

using test::damaged_copy;
using test::replay_file;

std::string temp_path(const std::string& name) { return test::temp_trace_path("replay_e2e", name); }

std::string describe(const replay::ReplayReport& r) { return replay::format_text(r); }

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kAsRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;

TEST(ReplayE2E, CleanEngineSceneReplaysWithEqualOutputs) {
    const std::string path = temp_path("clean.clt");
    {
        SceneTrace t(path, true);
        t.build({});
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_TRUE(r.engine_trace);
    EXPECT_EQ(r.counts.cluster_commands, 1u);
    EXPECT_EQ(r.counts.cluster_ops, 2u);
    EXPECT_EQ(r.counts.outputs_compared, 3u);  // addresses, sizes, objects
    EXPECT_GT(r.counts.output_bytes_compared, 600u);
    ASSERT_EQ(r.sizes.size(), 1u);
    EXPECT_EQ(r.sizes[0].ops_compared, 2u);
    EXPECT_EQ(r.sizes[0].sizes_equal, 2u);
    EXPECT_EQ(r.sizes[0].captured_bytes, r.sizes[0].engine_bytes);
    std::remove(path.c_str());
}

TEST(ReplayE2E, CapturedObjectByteThatDiffersIsReportedAtItsOp) {
    const std::string path = temp_path("corrupt.clt");
    uint64_t object_bytes = 0;
    {
        SceneTrace t(path, true);
        BuildCall call;
        call.corrupt_output_byte = 200;  // inside op 0's object (objects are > 200 bytes)
        t.build(call);
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.findings.size(), 1u) << describe(r);
    EXPECT_EQ(r.findings[0].rule, "CLASTRACE-replay-output-differs");
    EXPECT_EQ(r.findings[0].source, replay::FindingSource::kVerify);
    EXPECT_EQ(r.findings[0].op_index, 0);
    EXPECT_EQ(r.findings[0].address, SceneBuffers::kDst + 200);
    EXPECT_EQ(r.findings[0].where.command, 0u);
    (void)object_bytes;
    // --no-verify skips the comparison.
    replay::ReplayOptions o;
    o.verify_outputs = false;
    EXPECT_TRUE(replay_file(path, o).clean());
    std::remove(path.c_str());
}

void scratch_scene(const std::string& path, bool with_barrier) {
    SceneTrace t(path, true);
    t.build({});
    if (with_barrier) t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
    BuildCall second;
    second.dst = SceneBuffers::kDst2;
    second.addresses = SceneBuffers::kAddresses2;
    second.sizes = SceneBuffers::kSizes2;
    second.first_cluster_id = 200;
    t.build(second);  // same scratchData
    t.finish();
}

TEST(ReplayE2E, ScratchReusedWithoutBarrierIsOneHazardAtTheSecondBuild) {
    const std::string path = temp_path("scratch.clt");
    scratch_scene(path, false);
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterWrite);
    EXPECT_EQ(h.prior.command.command, 0u);
    EXPECT_EQ(h.later.command.command, 1u);
    EXPECT_TRUE(h.later.field.starts_with("scratchData (the ")) << h.later.field;
    EXPECT_GE(h.overlap.begin, SceneBuffers::kScratch);
    EXPECT_NE(h.format().find("SYNC-HAZARD-WRITE-AFTER-WRITE"), std::string::npos);
    std::remove(path.c_str());
}

TEST(ReplayE2E, ScratchReusedAfterBarrierIsClean) {
    const std::string path = temp_path("scratch_ok.clt");
    scratch_scene(path, true);
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.cluster_commands, 2u);
    EXPECT_EQ(r.counts.barriers, 1u);
    std::remove(path.c_str());
}

enum class Sync { kNone, kBarrierV1, kEvent, kEventSetBeforeTheFirstBuild };

void scratch_scene_with(const std::string& path, Sync sync) {
    SceneTrace t(path, true);
    if (sync == Sync::kEventSetBeforeTheFirstBuild)
        t.set_event(0xe1, kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
    t.build({});
    if (sync == Sync::kBarrierV1)
        t.barrier_v1(uint32_t(kBuild), uint32_t(kAsWrite), uint32_t(kBuild),
                     uint32_t(kAsRead | kAsWrite));
    if (sync == Sync::kEvent) t.set_event(0xe1, kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
    if (sync == Sync::kEvent || sync == Sync::kEventSetBeforeTheFirstBuild)
        t.wait_event(0xe1, kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
    BuildCall second;
    second.dst = SceneBuffers::kDst2;
    second.addresses = SceneBuffers::kAddresses2;
    second.sizes = SceneBuffers::kSizes2;
    second.first_cluster_id = 200;
    t.build(second);
    t.finish();
}

TEST(ReplayE2E, V1BarriersAndEventsOrderTheScratchReuse) {
    const std::string path = temp_path("sync_kinds.clt");
    scratch_scene_with(path, Sync::kBarrierV1);
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    scratch_scene_with(path, Sync::kEvent);
    r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.barriers, 2u);
    // An event set before the first build does not cover it.
    scratch_scene_with(path, Sync::kEventSetBeforeTheFirstBuild);
    r = replay_file(path);
    ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
    EXPECT_TRUE(r.hazards[0].later.field.starts_with("scratchData (the "))
        << r.hazards[0].later.field;
    std::remove(path.c_str());
}

void copy_scene(const std::string& path, bool with_barrier) {
    SceneTrace t(path, true);
    t.copy_infos();
    if (with_barrier)
        t.barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, kBuild,
                  VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    t.build({});
    t.finish();
}

TEST(ReplayE2E, InfosWrittenByCopyWithoutBarrierIsReadAfterWrite) {
    const std::string path = temp_path("copy.clt");
    copy_scene(path, false);
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kReadAfterWrite);
    EXPECT_EQ(std::string(h.prior.command.name), "vkCmdCopyBuffer");
    EXPECT_EQ(h.later.command.command, 1u);
    EXPECT_EQ(h.later.field, "srcInfosArray[*]");
    EXPECT_EQ(r.hazards_merged, 1u);
    EXPECT_EQ(h.overlap.begin, SceneBuffers::kInfos);
    EXPECT_EQ(h.overlap.end, SceneBuffers::kInfos + 2 * 64);
    EXPECT_EQ(h.fix.dst_stages & kBuild, kBuild);
    std::remove(path.c_str());
}

TEST(ReplayE2E, InfosWrittenByCopyWithTheRightBarrierIsClean) {
    const std::string path = temp_path("copy_ok.clt");
    copy_scene(path, true);
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.copies, 1u);
    std::remove(path.c_str());
}

TEST(ReplayE2E, ClusterIdAllOnesIsTheEngineVuidAtThatOp) {
    const std::string path = temp_path("vuid.clt");
    const std::string twin = temp_path("vuid_ok.clt");
    {
        SceneTrace t(path, true);
        t.infos[1].clusterID = 0xFFFFFFFFu;
        BuildCall call;
        call.capture_outputs = false;
        t.build(call);
        t.finish();
    }
    {
        SceneTrace t(twin, true);
        BuildCall call;
        call.capture_outputs = false;
        t.build(call);
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.findings.size(), 1u) << describe(r);
    EXPECT_EQ(r.findings[0].rule,
              "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterID-10488");
    EXPECT_EQ(r.findings[0].op_index, 1);
    EXPECT_EQ(r.findings[0].source, replay::FindingSource::kEngine);
    EXPECT_TRUE(replay_file(twin).clean());
    std::remove(path.c_str());
    std::remove(twin.c_str());
}

// A hostile trace's enum fields past Vulkan's 0x7FFFFFFF: the engine's findings, with the
// values as the trace holds them; replay and engine read such fields by their bits (under UBSan,
// loading them as the enums stopped the replay).
TEST(ReplayE2E, EnumFieldsPastTheEnumsRangeAreTheEngineVuids) {
    const struct {
        uint32_t vertex_format, op_type;
        const char* rule;
        const char* text;
    } cases[] = {
        {0xffffffffu, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
         "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-vertexFormat-10439",
         "vertexFormat -1 lacks"},
        {VK_FORMAT_R32G32B32_SFLOAT, 0x80000000u,
         "VUID-VkClusterAccelerationStructureInputInfoNV-opType-parameter",
         "input.opType = -2147483648 is not"},
    };
    for (const auto& c : cases) {
        SCOPED_TRACE(c.rule);
        const std::string path = temp_path("enum_bits.clt");
        {
            SceneTrace t(path, true);
            BuildCall call;
            call.capture_outputs = false;
            call.vertex_format = c.vertex_format;
            call.op_type = c.op_type;
            t.build(call);
            t.finish();
        }
        replay::ReplayReport r = replay_file(path);
        size_t named = 0;
        for (const auto& f : r.findings)
            if (f.rule == c.rule && f.source == replay::FindingSource::kEngine) {
                EXPECT_NE(f.message.find(c.text), std::string::npos) << f.message;
                ++named;
            }
        EXPECT_GE(named, 1u) << describe(r);
        std::remove(path.c_str());
    }
}

TEST(ReplayE2E, ScratchTooSmallIs12300AndEnoughScratchIsClean) {
    const std::string path = temp_path("scratch_small.clt");
    const std::string twin = temp_path("scratch_enough.clt");
    for (auto [file, size] : {std::pair{path, uint64_t{16}}, std::pair{twin, uint64_t{4096}}}) {
        SceneTrace t(file, true, size);
        BuildCall call;
        call.capture_outputs = false;
        t.build(call);
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    ASSERT_FALSE(r.findings.empty()) << describe(r);
    EXPECT_EQ(r.findings[0].rule,
              "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12300");
    EXPECT_TRUE(replay_file(twin).clean()) << describe(replay_file(twin));
    std::remove(path.c_str());
    std::remove(twin.c_str());
}

// A driver trace: the captured dstAddressesArray holds the driver's addresses, a BLAS
// references the clusters by them; replay must translate them to the rebuilt objects.
TEST(ReplayE2E, DriverAddressesInClusterReferencesAreTranslated) {
    const std::string path = temp_path("driver.clt");
    const uint64_t shift = 0x800;  // the driver packed its objects 2 KiB further on
    {
        SceneTrace t(path, false);
        t.driver_address_shift = shift;
        t.build({});
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.build_blas({SceneBuffers::kDst + shift, 0});  // second reference filled below
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    EXPECT_FALSE(r.engine_trace);
    // The second reference (0) is the engine's business; the first must translate.
    EXPECT_EQ(r.counts.addresses_translated, 1u) << describe(r);
    for (const auto& n : r.notes)
        EXPECT_NE(n.rule, "CLASTRACE-replay-reference-not-rebuilt") << n.format();
    EXPECT_EQ(r.counts.cluster_commands, 2u);
    std::remove(path.c_str());
}

TEST(ReplayE2E, DriverAddressesOfMoveSourcesAreTranslated) {
    const std::string path = temp_path("driver_move.clt");
    const uint64_t shift = 0x800;
    {
        SceneTrace t(path, false);
        t.driver_address_shift = shift;
        t.build({});
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.move_clusters({SceneBuffers::kDst + shift});
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    EXPECT_TRUE(r.hazards.empty()) << describe(r);
    EXPECT_EQ(r.counts.addresses_translated, 1u);
    EXPECT_EQ(r.counts.cluster_ops, 3u);
    std::remove(path.c_str());
}

TEST(ReplayE2E, DriverReferenceToAnObjectNeverRebuiltIsReported) {
    const std::string path = temp_path("driver_bad.clt");
    {
        SceneTrace t(path, false);
        t.driver_address_shift = 0x800;
        t.build({});
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.build_blas({SceneBuffers::kDst2 + 0x4000 + 0x800});  // nothing was built there
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    bool found = false;  // a limit of the replay: a note
    for (const auto& f : r.notes)
        if (f.rule == "CLASTRACE-replay-reference-not-rebuilt") {
            found = true;
            EXPECT_EQ(f.where.command, 2u);
            EXPECT_EQ(f.op_index, 0);
        }
    EXPECT_TRUE(found) << describe(r);
    std::remove(path.c_str());
}

void two_queue_scene(const std::string& path, bool semaphore) {
    SceneTrace t(path, true);
    t.build({});
    t.submit(0x9001, 0, semaphore ? 0x5e1 : 0);
    BuildCall second;
    second.dst = SceneBuffers::kDst2;
    second.addresses = SceneBuffers::kAddresses2;
    second.sizes = SceneBuffers::kSizes2;
    second.first_cluster_id = 300;
    t.build(second);  // same scratch, on another queue
    t.submit(0x9002, semaphore ? 0x5e1 : 0, 0);
    t.finish();
}

TEST(ReplayE2E, ScratchSharedAcrossQueuesNeedsASemaphore) {
    const std::string path = temp_path("queues.clt");
    two_queue_scene(path, false);
    replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
    EXPECT_EQ(r.hazards[0].fix.kind, replay::FixKind::kSemaphore);
    EXPECT_EQ(r.hazards[0].later.command.submission, 1u);
    EXPECT_TRUE(r.hazards[0].later.field.starts_with("scratchData (the "))
        << r.hazards[0].later.field;
    two_queue_scene(path, true);
    r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.submissions, 3u);
    std::remove(path.c_str());
}

// Long random streams of copies and builds, each step behind a full barrier: no hazard,
// no finding, every captured output equal.
TEST(ReplayE2E, RandomValidStreamsHaveNoFalsePositives) {
    std::mt19937_64 rng(7);
    const std::string path = temp_path("stream.clt");
    for (int round = 0; round < 4; ++round) {
        {
            SceneTrace t(path, true);
            for (int step = 0; step < 40; ++step) {
                t.barrier(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT,
                          VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                          VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
                switch (rng() % 4) {
                case 0: t.copy_infos(); break;
                case 1:
                    t.submit(0x9001);
                    break;  // same queue: the next barrier orders across submissions
                default: {
                    BuildCall call;
                    const bool second = rng() % 2;
                    call.dst = second ? SceneBuffers::kDst2 : SceneBuffers::kDst;
                    call.addresses = second ? SceneBuffers::kAddresses2 : SceneBuffers::kAddresses;
                    call.sizes = second ? SceneBuffers::kSizes2 : SceneBuffers::kSizes;
                    call.first_cluster_id = uint32_t(rng() % 100000);
                    t.build(call);
                }
                }
            }
            t.finish();
        }
        replay::ReplayReport r = replay_file(path);
        EXPECT_TRUE(r.clean()) << describe(r);
        EXPECT_GT(r.counts.outputs_compared, 0u);
    }
    std::remove(path.c_str());
}

// The host rewrites srcInfosArray (mapped memory) while a submission that reads it may
// still run: a hazard unless the host waited for the submission's fence first.
void host_scene(const std::string& path, bool wait, bool same_bytes) {
    SceneTrace t(path, true);
    t.build({});
    t.submit(0x9001, 0, 0, 0xfe2);
    if (wait) t.wait_fence(0xfe2);
    auto infos = t.infos;
    if (!same_bytes) infos[1].clusterID = 777;
    const auto* p = reinterpret_cast<const uint8_t*>(infos.data());
    t.observe(SceneBuffers::kInfos, std::vector<uint8_t>(p, p + infos.size() * sizeof infos[0]));
    t.finish();
}

TEST(ReplayE2E, HostRewriteOfBuildInputsNeedsAFenceWait) {
    const std::string path = temp_path("host.clt");
    host_scene(path, false, false);
    replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
    EXPECT_EQ(r.hazards[0].hazard, replay::HazardClass::kWriteAfterRead);
    EXPECT_EQ(r.hazards[0].fix.kind, replay::FixKind::kHostWait);
    // Only the changed bytes count as written: the low two bytes of op 1's clusterID (101 -> 777).
    EXPECT_EQ(r.hazards[0].later.range.begin, SceneBuffers::kInfos + 64);
    EXPECT_EQ(r.hazards[0].later.range.end, SceneBuffers::kInfos + 64 + 2);
    host_scene(path, true, false);
    r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    host_scene(path, false, true);  // observed but unchanged: no host write
    r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    std::remove(path.c_str());
}

// The capture saw the build read src infos the host rewrote after vkQueueSubmit (reason 4): the
// replay's image already holds those bytes (they are the build's input snapshot), yet the whole
// range is the host's write, racing with the build unless the host waited for the fence first.
// Returns the bytes observed.
size_t host_rewrite_read_by_build(const std::string& path, bool wait) {
    SceneTrace t(path, true);
    t.build({});
    t.submit(0x9001, 0, 0, 0xfe2);
    if (wait) t.wait_fence(0xfe2);
    const auto* p = reinterpret_cast<const uint8_t*>(t.infos.data());
    t.observe(SceneBuffers::kInfos, std::vector<uint8_t>(p, p + t.infos.size() * sizeof t.infos[0]),
              4);
    t.finish();
    return t.infos.size() * sizeof t.infos[0];
}

TEST(ReplayE2E, HostRewriteTheBuildReadIsAHostWriteRace) {
    const std::string path = temp_path("host_read_by_build.clt");
    const size_t observed = host_rewrite_read_by_build(path, false);
    replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterRead);
    EXPECT_EQ(h.later.queue, replay::kHostQueue);
    EXPECT_EQ(h.later.range.begin, SceneBuffers::kInfos);
    EXPECT_EQ(h.later.range.end, SceneBuffers::kInfos + observed);
    const std::string text = h.format();
    EXPECT_NE(text.find("HOST-WRITE race"), std::string::npos) << text;
    EXPECT_NE(text.find("submit 0"), std::string::npos) << text;
    EXPECT_NE(text.find("wait on that submission's fence"), std::string::npos) << text;
    EXPECT_NE(text.find("double-buffer"), std::string::npos) << text;
    host_rewrite_read_by_build(path, true);
    r = replay_file(path);
    EXPECT_TRUE(r.clean()) << describe(r);
    std::remove(path.c_str());
}

// Memory beyond the budget is refused and named, not allocated (regions are sparse: the
// budget counts the pages written).
TEST(ReplayE2E, BuffersBeyondTheMemoryBudgetAreReportedNotAllocated) {
    const std::string path = temp_path("budget.clt");
    {
        SceneTrace t(path, true);
        t.build({});
        t.finish();
    }
    replay::ReplayOptions o;
    o.memory_budget_bytes =
        0x3000;  // three pages: the input snapshots fit, the engine's outputs do not
    replay::ReplayReport r = replay_file(path, o);
    bool budget = false;
    for (const auto& n : r.notes) budget |= n.rule == "CLASTRACE-replay-memory-budget";
    EXPECT_TRUE(budget) << describe(r);  // a limit of the replay: a note, not a finding
    EXPECT_TRUE(replay_file(path).clean());
    std::remove(path.c_str());
}

TEST(ReplayE2E, SlicesSelectCommands) {
    const std::string path = temp_path("slice.clt");
    scratch_scene(path, false);
    replay::ReplayOptions o;
    o.first_command = 1;
    o.last_command = 1;
    replay::ReplayReport r = replay_file(path, o);
    EXPECT_EQ(r.counts.cluster_commands, 1u);
    EXPECT_EQ(r.counts.skipped_commands, 1u);
    EXPECT_TRUE(r.hazards.empty());  // the first build is outside the slice
    o = {};
    o.submission = 5;
    r = replay_file(path, o);
    EXPECT_EQ(r.counts.commands, 0u);
    o = {};
    o.check_hazards = false;
    r = replay_file(path, o);
    EXPECT_TRUE(r.hazards.empty());
    EXPECT_EQ(r.counts.cluster_commands, 2u);
    std::remove(path.c_str());
}

// Hostile srcInfos contents, strides and addresses: the replay must finish without crashing.
TEST(ReplayE2E, RandomMutationsOfAValidSceneNeverCrash) {
    std::mt19937_64 rng(1234);
    const std::string path = temp_path("mutant.clt");
    for (int round = 0; round < 150; ++round) {
        {
            SceneTrace t(path, round % 2 == 0);
            t.driver_address_shift = (rng() % 4) * 0x100;
            auto* bytes = reinterpret_cast<uint8_t*>(t.infos.data());
            const size_t n = t.infos.size() * sizeof t.infos[0];
            for (int k = 0, flips = 1 + int(rng() % 8); k < flips; ++k)
                bytes[rng() % n] ^= uint8_t(1u << (rng() % 8));
            if (rng() % 3 == 0) t.infos[rng() % 2].vertexBuffer = rng();
            BuildCall call;
            call.capture_outputs = rng() % 2;
            if (rng() % 4 == 0) call.scratch = SceneBuffers::kScratch + (rng() % 64);
            try {
                t.build(call);
                if (rng() % 2) t.build_blas({SceneBuffers::kDst + (rng() % 3) * 0x100, rng()});
                t.finish();
            } catch (const std::exception&) {
                continue;  // the mirror engine refused the scene; nothing to replay
            }
        }
        replay::ReplayReport r = replay_file(path);
        EXPECT_GE(r.counts.records, 1u);
    }
    std::remove(path.c_str());
}

TEST(ReplayE2E, ShippedSampleReplaysCleanWithDriverSizesSideBySide) {
    replay::ReplayReport r = replay_file(CLASTRACE_SAMPLE);
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_FALSE(r.engine_trace);
    EXPECT_EQ(r.counts.cluster_commands, 1u);
    ASSERT_EQ(r.sizes.size(), 1u);
    EXPECT_EQ(r.sizes[0].ops_compared, 2u);
    EXPECT_EQ(r.sizes[0].captured_bytes, 2u * 7936u);  // what the sample's "driver" answered
    EXPECT_GT(r.sizes[0].engine_bytes, 0u);
    ASSERT_EQ(r.sizes[0].first_ops.size(), 2u);
    EXPECT_EQ(r.sizes[0].first_ops[1].op, 1u);
    EXPECT_EQ(r.sizes[0].first_ops[1].captured, 7936u);
    EXPECT_EQ(r.sizes[0].first_ops[0].engine + r.sizes[0].first_ops[1].engine,
              r.sizes[0].engine_bytes);
    // Its vkCmdBuildAccelerationStructureNV is replayed by the engine (nv_command.cpp).
    EXPECT_TRUE(r.not_replayed.empty());
    EXPECT_EQ(r.counts.nv_builds, 1u);
    ASSERT_EQ(r.nv_sizes.size(), 1u);
    EXPECT_GT(r.nv_sizes[0].engine_bytes, 0u);
    EXPECT_GT(r.counts.accesses, 10u);
}

// The sizes table names each command's op type as `clastrace analyze` does, not by number.
TEST(ReplayE2E, SizesTableNamesEveryOpType) {
    replay::ReplayReport r;
    const std::vector<std::pair<uint32_t, std::string>> names = {
        {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV, "move_objects"},
        {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
         "build_clusters_bottom_level"},
        {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
         "build_triangle_cluster"},
        {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
         "build_triangle_cluster_template"},
        {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
         "instantiate_triangle_cluster"},
        {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV,
         "get_cluster_template_indices"},
        {77, "other"}};
    for (const auto& [type, name] : names) {
        replay::SizeComparison row;
        row.where.command = type;
        row.op_type = type;
        r.sizes.push_back(row);
    }
    const std::string text = replay::format_text(r);
    for (const auto& [type, name] : names) {
        const std::string row_start = "  s0 cb0 cmd" + std::to_string(type) + " ";
        const size_t at = text.find(row_start);
        ASSERT_NE(at, std::string::npos) << text;
        const std::string row = text.substr(at, text.find('\n', at) - at);
        EXPECT_NE(row.find(" " + name + " "), std::string::npos) << row;
    }
}

// Damaged files (flipped bytes, cut tails): the reader skips what fails its checks and the
// replay reports the damage; nothing crashes.
TEST(ReplayE2E, FlippedAndTruncatedTraceFilesNeverCrash) {
    const std::string clean = temp_path("flip_src.clt");
    copy_scene(clean, true);
    std::ifstream in(clean, std::ios::binary);
    std::vector<char> bytes((std::istreambuf_iterator<char>(in)), {});
    ASSERT_GT(bytes.size(), 200u);
    std::mt19937_64 rng(99);
    const std::string path = temp_path("flip.clt");
    int damaged = 0;
    for (int round = 0; round < 60; ++round) {
        const std::vector<char> mutant = damaged_copy(bytes, round, rng);
        std::ofstream(path, std::ios::binary).write(mutant.data(), std::streamsize(mutant.size()));
        traces::TraceError e;
        auto reader = traces::TraceReader::open(path, &e);
        if (!reader) continue;
        replay::ReplayReport r = replay::replay_trace(*reader, path);
        if (!r.trace_damage.empty()) {
            ++damaged;
            EXPECT_FALSE(r.clean());
        }
    }
    EXPECT_GT(damaged, 0);
    std::remove(path.c_str());
    std::remove(clean.c_str());
}

int run_cli(const std::string& args, std::string* out) {
    const std::string out_path = temp_path("cli.out");
    const std::string cmd =
        std::string(CLASTRACE_BIN) + " " + args + " > " + out_path + " 2>/dev/null";
    int status = std::system(cmd.c_str());
    std::ifstream in(out_path);
    out->assign(std::istreambuf_iterator<char>(in), {});
    std::remove(out_path.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(ReplayCli, ExitCodesAndJsonShape) {
    std::string out;
    EXPECT_EQ(run_cli(std::string("replay ") + CLASTRACE_SAMPLE, &out), 0) << out;
    EXPECT_NE(out.find("result: clean"), std::string::npos) << out;
    // The sample's one cluster command builds two CLAS: its row names the op type.
    const size_t row = out.find("  s0 cb");
    ASSERT_NE(row, std::string::npos) << out;
    EXPECT_NE(out.substr(row, out.find('\n', row) - row).find(" build_triangle_cluster "),
              std::string::npos)
        << out;

    const std::string hazard = temp_path("cli_hazard.clt");
    scratch_scene(hazard, false);
    EXPECT_EQ(run_cli("replay " + hazard, &out), 1);
    EXPECT_EQ(out.rfind("SYNC-HAZARD-WRITE-AFTER-WRITE", 0), 0u) << out;
    EXPECT_EQ(run_cli("replay --no-hazards " + hazard, &out), 0) << out;

    EXPECT_EQ(run_cli("replay --json " + hazard, &out), 1);
    nlohmann::json j = nlohmann::json::parse(out);
    EXPECT_EQ(j["clean"], false);
    EXPECT_EQ(j["engine_trace"], true);
    ASSERT_EQ(j["hazards"]["hazards"].size(), 1u);
    EXPECT_EQ(j["hazards"]["hazards"][0]["class"], "WRITE-AFTER-WRITE");
    EXPECT_EQ(j["counts"]["cluster_commands"], 2);
    EXPECT_TRUE(j["findings"].is_array());
    EXPECT_TRUE(j["sizes"].is_array());
    EXPECT_TRUE(j["not_replayed"].is_array());

    EXPECT_EQ(run_cli("replay /nonexistent/trace.clt", &out), 2);
    EXPECT_EQ(run_cli("replay --json /nonexistent/trace.clt", &out), 2);
    EXPECT_TRUE(nlohmann::json::parse(out).contains("error"));
    EXPECT_EQ(run_cli("replay --ops 5..2 " + hazard, &out), 2);
    EXPECT_EQ(run_cli("replay --bogus " + hazard, &out), 2);
    EXPECT_EQ(run_cli("replay --ops 1..1 " + hazard, &out), 0) << out;
    EXPECT_EQ(run_cli("replay --help", &out), 0);
    std::remove(hazard.c_str());
}

}  // namespace
