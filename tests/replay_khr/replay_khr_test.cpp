// SPDX-License-Identifier: Apache-2.0
// Replay of KHR acceleration-structure traces written here as the capture records them: KHR
// builds on the engine, a top level whose instances name KHR, NV and cluster BLASes traced
// through each, the build-time findings (an instance naming no built BLAS, a null cluster
// reference), a missing barrier before a KHR build, compaction and property queries.
#include "khr_trace.h"

#include <clastrace/engine/blas.h>
#include <clastrace/engine/khr_build.h>
#include <clastrace/replay/hazard_report.h>
#include <clastrace/trace_building/khr_records.h>

#include <gtest/gtest.h>

#include "trace_files.h"

namespace clastrace::khrtest {
namespace {

namespace tb = trace_building;

std::string temp_path(const std::string& name) { return test::temp_trace_path("replay_khr", name); }

// An instance of `reference` moved `x` along x.
std::array<uint8_t, 64> instance_at(float x, uint64_t reference, uint32_t custom_index = 0) {
    return tb::instance_bytes({1, 0, 0, x, 0, 1, 0, 0, 0, 0, 1, 0}, custom_index, 0xFF, 0, 0,
                              reference);
}

engine::KhrBuildCommand one(engine::KhrBuildInfo info) {
    engine::KhrBuildCommand c;
    c.infos.push_back(std::move(info));
    return c;
}

TEST(ReplayKhr, BottomAndTopLevelReplayCleanAndTheirRaysAgree) {
    KhrTrace t(temp_path("clean.clt"), true);
    const auto blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    t.build(one(t.triangle_blas(blas)));
    t.build_barrier();
    t.build(one(t.top_level(tlas, {instance_at(0, blas.address)})));
    t.submit();
    t.ray_check(tlas, {ray_through(0.25f, 0.25f, 0)});
    const replay::ReplayReport r = t.replay();
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.khr_builds, 2u);
    ASSERT_EQ(r.ray_checks.size(), 1u) << describe(r);
    EXPECT_TRUE(r.ray_checks[0].checked) << r.ray_checks[0].why_not;
    EXPECT_EQ(r.ray_checks[0].agree_hit, 1u) << describe(r);
    EXPECT_EQ(r.ray_checks[0].disagree, 0u);
}

// Each build's input snapshots (the vertices, the top level's instances) are laid into replay
// memory once, by the build: noting what the top level's instances name reads them from there.
TEST(ReplayKhr, EachBuildInputIsLaidIntoMemoryOnce) {
    KhrTrace t(temp_path("laid_once.clt"), true);
    const auto blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    t.build(one(t.triangle_blas(blas)));
    t.build_barrier();
    t.build(one(t.top_level(tlas, {instance_at(0, blas.address)})));
    t.submit();
    const replay::ReplayReport r = t.replay();
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.snapshots_applied, 2u) << describe(r);
    EXPECT_EQ(r.counts.snapshot_bytes, 9 * sizeof(float) + 64) << describe(r);
}

// One top level over a KHR BLAS (x = 0), an NV BLAS (x = 10, named by its NV handle) and a
// cluster BLAS (x = 20, named by the address its cluster build wrote): a ray through each
// instance hits that instance's triangle.
TEST(ReplayKhr, TopLevelInstancesReachKhrNvAndClusterBottomLevels) {
    KhrTrace t(temp_path("kinds.clt"), true);
    const auto khr_blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    t.build(one(t.triangle_blas(khr_blas)));
    const auto nv_blas = t.nv_triangle_blas();
    const uint64_t cluster_blas = t.cluster_triangle_blas();
    t.build_barrier();
    t.build(
        one(t.top_level(tlas, {instance_at(0, khr_blas.address), instance_at(10, nv_blas.address),
                               instance_at(20, cluster_blas)})));
    t.submit();
    CheckedRay beside = ray_through(20.8f, 0.8f, 2);  // x + y > 1: outside the triangle
    beside.hit = false;
    t.ray_check(tlas, {ray_through(0.25f, 0.25f, 0), ray_through(10.25f, 0.25f, 1),
                       ray_through(20.25f, 0.5f, 2), beside});
    const replay::ReplayReport r = t.replay();
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    EXPECT_TRUE(r.hazards.empty()) << describe(r);
    ASSERT_EQ(r.ray_checks.size(), 1u) << describe(r);
    ASSERT_TRUE(r.ray_checks[0].checked) << r.ray_checks[0].why_not;
    EXPECT_EQ(r.ray_checks[0].agree_hit, 3u) << describe(r);
    EXPECT_EQ(r.ray_checks[0].agree_miss, 1u) << describe(r);
    EXPECT_EQ(r.ray_checks[0].disagree, 0u) << describe(r);
}

// A driver's trace: the instance names the cluster BLAS by the address the driver wrote into
// dstAddressesArray (implicit mode); replay finds the BLAS where the engine rebuilt it.
TEST(ReplayKhr, InstanceNamingADriversClusterBlasAddressReachesTheRebuiltOne) {
    constexpr uint64_t kDriverAddress = 0x7F12'3400'0000ull;
    KhrTrace t(temp_path("driver_cluster.clt"), false);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    ASSERT_EQ(t.cluster_triangle_blas(false, kDriverAddress), kDriverAddress);
    t.build_barrier();
    t.build(one(t.top_level(tlas, {instance_at(0, kDriverAddress)})));
    t.submit();
    t.ray_check(tlas, {ray_through(0.25f, 0.25f, 0)});
    const replay::ReplayReport r = t.replay();
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    EXPECT_GE(r.counts.handles_translated, 1u);
    ASSERT_EQ(r.ray_checks.size(), 1u) << describe(r);
    EXPECT_EQ(r.ray_checks[0].agree_hit, 1u) << describe(r);
}

TEST(ReplayKhr, InstanceNamingAnUnbuiltBottomLevelIsAFindingAtTheTopLevelBuild) {
    KhrTrace t(temp_path("unbuilt.clt"), true);
    const auto built = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto never_built = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    t.build(one(t.triangle_blas(built)));
    t.build_barrier();
    t.build(one(
        t.top_level(tlas, {instance_at(0, built.address), instance_at(10, never_built.address)})));
    t.submit();
    const replay::ReplayReport r = t.replay();
    EXPECT_EQ(count_rule(r, engine::kRuleKhrBlasNotBuilt), 1u) << describe(r);
    bool named = false;
    for (const auto& f : r.findings)
        named |= f.rule == engine::kRuleKhrBlasNotBuilt &&
                 f.message.find("pInfos[0].pGeometries[0].geometry.instances.data[1]") !=
                     std::string::npos;
    EXPECT_TRUE(named) << describe(r);
}

// In a driver's trace an address that no created structure and no rebuilt cluster BLAS has
// names nothing: the reference rule.
TEST(ReplayKhr, InstanceNamingNoStructureInADriversTraceBreaksTheReferenceRule) {
    KhrTrace t(temp_path("nothing.clt"), false);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    t.build(one(t.top_level(tlas, {instance_at(0, 0xDEAD0000)})));
    t.submit();
    const replay::ReplayReport r = t.replay();
    EXPECT_EQ(count_rule(r, engine::kVuidKhrReference), 1u) << describe(r);
}

TEST(ReplayKhr, NullClusterReferenceIsAFindingAndTheOtherClusterStillTraces) {
    KhrTrace t(temp_path("null_reference.clt"), true);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    const uint64_t cluster_blas = t.cluster_triangle_blas(true);
    t.build_barrier();
    t.build(one(t.top_level(tlas, {instance_at(0, cluster_blas)})));
    t.submit();
    t.ray_check(tlas, {ray_through(0.25f, 0.25f, 0)});
    const replay::ReplayReport r = t.replay();
    ASSERT_EQ(count_rule(r, engine::kRuleStaleClusterReference), 1u) << describe(r);
    bool named = false;
    for (const auto& f : r.findings)
        named |= f.rule == engine::kRuleStaleClusterReference &&
                 f.message.find("clusterReferences[1]") != std::string::npos &&
                 f.message.find("address is 0") != std::string::npos;
    EXPECT_TRUE(named) << describe(r);
    ASSERT_EQ(r.ray_checks.size(), 1u);
    EXPECT_EQ(r.ray_checks[0].agree_hit, 1u) << describe(r);
}

// Vulkan-ValidationLayers #7372: vertices copied into place, then a BLAS build reading them
// with no barrier between: a read-after-write hazard naming both commands; the barrier fixes it.
TEST(ReplayKhr, MissingBarrierBetweenVertexCopyAndKhrBuildIsReadAfterWrite) {
    for (const bool with_barrier : {false, true}) {
        KhrTrace t(temp_path("vertex_copy.clt"), true);
        const std::vector<float> v = triangle_vertices();
        const uint64_t staging = t.buffer(v.data(), v.size() * 4, VK_BUFFER_USAGE_TRANSFER_SRC_BIT);
        const uint64_t vertices =
            t.buffer(nullptr, v.size() * 4,
                     VK_BUFFER_USAGE_TRANSFER_DST_BIT |
                         VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR);
        const auto blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
        t.copy_buffer(staging, vertices, v.size() * 4);
        if (with_barrier)
            t.barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                      VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                      VK_ACCESS_2_SHADER_READ_BIT);
        t.build(one(t.triangle_blas(blas, vertices)));
        t.submit();
        const replay::ReplayReport r = t.replay();
        EXPECT_TRUE(r.findings.empty()) << describe(r);
        if (with_barrier) {
            EXPECT_TRUE(r.hazards.empty()) << describe(r);
            continue;
        }
        ASSERT_EQ(r.hazards.size(), 1u) << describe(r);
        const replay::HazardReport& h = r.hazards[0];
        EXPECT_EQ(h.hazard, replay::HazardClass::kReadAfterWrite);
        EXPECT_EQ(std::string(h.prior.command.name), "vkCmdCopyBuffer");
        EXPECT_EQ(std::string(h.later.command.name), "vkCmdBuildAccelerationStructuresKHR");
        EXPECT_NE(h.later.field.find("vertexData"), std::string::npos) << h.format();
    }
}

// ALLOW_COMPACTION build, its compacted size queried and read back (the driver's answer
// differs from the engine's by design: a note), a compacting copy, a top level over the copy.
TEST(ReplayKhr, CompactedCopyAndPropertyQueryAreAnsweredByTheEngine) {
    constexpr uint64_t kPool = 0x9001;
    KhrTrace t(temp_path("compact.clt"), true);
    const auto blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto compact = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    engine::KhrBuildInfo info = t.triangle_blas(blas);
    info.flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR;
    t.build(one(info));
    t.build_barrier();
    t.command(tb::acceleration_structure_properties(
        t.command_buffer(), 1, {blas.handle},
        VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR, kPool, 0));
    t.submit();
    t.host(tb::query_pool_results(kPool, 0, {123}));
    t.command(tb::acceleration_structure_copy(t.command_buffer(), 1, blas.handle, compact.handle,
                                              VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR));
    t.build_barrier();
    t.build(one(t.top_level(tlas, {instance_at(0, compact.address)})));
    t.submit();
    t.ray_check(tlas, {ray_through(0.25f, 0.25f, 0)});
    const replay::ReplayReport r = t.replay();
    EXPECT_TRUE(r.clean()) << describe(r);
    EXPECT_EQ(r.counts.khr_copies, 1u);
    EXPECT_EQ(r.counts.query_answers, 1u);
    ASSERT_EQ(count_rule(r, "CLASTRACE-replay-khr-query-answer-differs"), 1u) << describe(r);
    EXPECT_NE(r.notes[0].message.find("the driver answered 123"), std::string::npos)
        << r.notes[0].message;
    ASSERT_EQ(r.ray_checks.size(), 1u);
    EXPECT_EQ(r.ray_checks[0].agree_hit, 1u) << describe(r);
}

TEST(ReplayKhr, CompactingAStructureBuiltWithoutAllowCompactionIsAFinding) {
    KhrTrace t(temp_path("no_compaction.clt"), true);
    const auto blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto compact = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto never_built = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    t.build(one(t.triangle_blas(blas)));
    t.build_barrier();
    t.command(tb::acceleration_structure_copy(t.command_buffer(), 1, blas.handle, compact.handle,
                                              VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR));
    t.command(tb::acceleration_structure_copy(t.command_buffer(), 1, never_built.handle,
                                              compact.handle,
                                              VK_COPY_ACCELERATION_STRUCTURE_MODE_CLONE_KHR));
    t.submit();
    const replay::ReplayReport r = t.replay();
    EXPECT_EQ(count_rule(r, "VUID-VkCopyAccelerationStructureInfoKHR-src-03411"), 1u)
        << describe(r);
    EXPECT_EQ(count_rule(r, "VUID-VkCopyAccelerationStructureInfoKHR-src-04963"), 1u)
        << describe(r);
}

}  // namespace
}  // namespace clastrace::khrtest

namespace clastrace::khrtest {
namespace {

// A top level whose scratch holds exactly what the driver answered for it (64 bytes, less
// than the engine's own build scratch) replays clean in an engine trace too: a served trace's
// KHR builds ran on the device's driver, and the application sized scratch by its answer
// (GetAccelerationStructureBuildSizesKHR), as in a driver's trace. Without an answer in the
// trace, an engine trace's scratch is held to the engine's own size.
replay::ReplayReport replay_top_level_with_small_scratch(const std::string& name,
                                                         bool with_answer) {
    KhrTrace t(temp_path(name), true);
    const auto blas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
    const auto tlas = t.create(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    t.build(one(t.triangle_blas(blas)));
    t.build_barrier();
    constexpr uint64_t kDriverScratch = 64;
    engine::KhrBuildInfo top = t.top_level(tlas, {instance_at(0, blas.address)});
    top.scratch_address =
        t.address_of(t.buffer(nullptr, kDriverScratch, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT));
    if (with_answer) {
        fbs::GetAccelerationStructureBuildSizesKHRT sizes;
        sizes.build_type = VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR;
        sizes.info = std::move(tb::khr_build(0, one(top)).infos[0]);
        sizes.max_primitive_counts = {1};
        sizes.acceleration_structure_size = 1 << 12;
        sizes.build_scratch_size = kDriverScratch;
        t.host(std::move(sizes));
    }
    t.build(one(std::move(top)));
    t.submit();
    return t.replay();
}

TEST(ReplayKhr, EngineTracesJudgeKhrScratchByTheDriversAnswerWhereTheyHoldOne) {
    constexpr const char* kScratchRule = "VUID-vkCmdBuildAccelerationStructuresKHR-pInfos-03671";
    const replay::ReplayReport answered = replay_top_level_with_small_scratch("answered.clt", true);
    EXPECT_EQ(count_rule(answered, kScratchRule), 0u) << describe(answered);
    EXPECT_TRUE(answered.clean()) << describe(answered);
    EXPECT_EQ(answered.counts.khr_builds, 2u);
    const replay::ReplayReport unanswered =
        replay_top_level_with_small_scratch("unanswered.clt", false);
    EXPECT_EQ(count_rule(unanswered, kScratchRule), 1u) << describe(unanswered);
}

}  // namespace
}  // namespace clastrace::khrtest
