// SPDX-License-Identifier: Apache-2.0
// Cluster builds run ahead of their turn (replay/src/cluster_speculation.h, docs/replay.md
// "Threads"): a run stands only when every byte it read is unchanged at its turn, so a build that
// reads an earlier command's output outside its snapshots runs again in place; builds writing
// the same bytes land in queue order; a cluster BLAS runs on the CLAS runs before it and stands
// only when the replay's directory holds the objects it found as its own did. Each case compares
// the replay memory after every command and the JSON report of 1 and 4 threads, and counts which
// runs stood.
#include "cluster_speculation.h"
#include "replay_bench_trace.h"
#include "replayer_internal.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/properties.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/testsupport/temp_trace_path.h>
#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/trace_building/trace_header.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

using namespace clastrace;
namespace tb = clastrace::trace_building;

namespace {

using Info = VkClusterAccelerationStructureBuildTriangleClusterInfoNV;

constexpr uint64_t kQueue = 0x9001, kMemory = 0x1001, kCommandBuffer = 0xc001, kFence = 0xfe01;
constexpr uint64_t kVertices = 0x100000000ull, kIndices = 0x100010000ull, kInfos = 0x100020000ull,
                   kScratch = 0x100030000ull, kObjects = 0x100100000ull,
                   kAddresses = 0x100200000ull, kSizes = 0x100210000ull;
constexpr uint64_t kSda = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
constexpr uint64_t kInput = kSda |
                            VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
                            VK_BUFFER_USAGE_TRANSFER_DST_BIT;
constexpr uint64_t kStorage = kSda | VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                              VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kAsRead =
    VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR | VK_ACCESS_2_SHADER_READ_BIT;
constexpr uint32_t kGridVertices = 9, kGridTriangles = 8;  // a 2 x 2 quad grid

std::string temp_path(const std::string& name) {
    return test::temp_trace_path("replay_run_ahead", name);
}

// The replay bench's cluster frames, about `ops` cluster ops, written to a temporary trace.
std::string bench_frames(const std::string& name, uint64_t ops) {
    const std::string path = temp_path(name);
    bench::BenchTraceShape shape;
    shape.target_ops = ops;
    bench::write_bench_trace(path, shape);
    return path;
}

std::vector<float> grid(float x, float z) {
    std::vector<float> v;
    for (int row = 0; row < 3; ++row)
        for (int col = 0; col < 3; ++col) {
            v.push_back(x + float(col));
            v.push_back(float(row));
            v.push_back(z + 0.25f * float(row * col));
        }
    return v;
}

std::vector<uint8_t> grid_indices() {
    std::vector<uint8_t> i;
    for (uint8_t row = 0; row < 2; ++row)
        for (uint8_t col = 0; col < 2; ++col) {
            const uint8_t a = uint8_t(row * 3 + col), b = uint8_t(a + 1), c = uint8_t(a + 3),
                          d = uint8_t(c + 1);
            for (uint8_t k : {a, b, c, b, d, c}) i.push_back(k);
        }
    return i;
}

// One command buffer of one-cluster CLAS builds over a 2 x 2 grid, written with the trace
// builder as a capture on the engine would write it.
class BuildsTrace {
public:
    explicit BuildsTrace(const std::string& path) : w_(path, header()) {
        limits_ = tb::triangle_cluster_limits(kGridTriangles, kGridVertices, kGridTriangles,
                                              kGridVertices);
        sizes_ = engine::cluster_build_sizes(input(), engine::EngineProperties::nvidia_default());
        uint64_t handle = 0xb001;
        for (auto [address, size, usage] : {std::tuple{kVertices, 4096ull, kInput},
                                            {kIndices, 4096ull, kInput},
                                            {kInfos, 4096ull, kInput},
                                            {kScratch, 1ull << 16, kStorage},
                                            {kObjects, 1ull << 20, kStorage},
                                            {kAddresses, 4096ull, kStorage},
                                            {kSizes, 4096ull, kStorage}})
            w_.buffer(handle++, address, size, usage, kMemory, address - kVertices);
        w_.append(tb::command_buffer_begin(kCommandBuffer));
    }

    // A build of the cluster whose vertices are at kVertices + vertex_offset, its info at
    // info_slot, its object at kObjects + object_offset. `snapshots` lists the (address, bytes)
    // its capture saw; empty: its info, its indices and all its vertices.
    void build(uint64_t vertex_offset, const std::vector<float>& vertices, uint32_t info_slot,
               uint64_t object_offset,
               std::vector<std::pair<uint64_t, std::vector<uint8_t>>> seen = {}) {
        const Info info = tb::triangle_cluster_info(info_slot, kGridTriangles, kGridVertices,
                                                    kIndices, 1, kVertices + vertex_offset);
        const uint64_t info_at = kInfos + info_slot * sizeof(Info);
        seen.insert(seen.begin(), {info_at, tb::bytes_of(&info, 1)});
        if (seen.size() == 1) {
            seen.push_back({kIndices, grid_indices()});
            seen.push_back({kVertices + vertex_offset, tb::bytes_of(vertices)});
        }
        auto commands = tb::cluster_commands(input());
        commands.dstImplicitData = kObjects + object_offset;
        commands.scratchData = kScratch;
        commands.dstAddressesArray = {kAddresses + info_slot * 8, 8, 8};
        commands.dstSizesArray = {kSizes + info_slot * 4, 4, 4};
        commands.srcInfosArray = {info_at, sizeof(Info), sizeof(Info)};
        fbs::CmdBuildClusterAccelerationStructureIndirectT b =
            tb::cluster_build(kCommandBuffer, commands);
        for (const auto& [address, bytes] : seen) b.inputs.push_back(w_.snapshot(address, bytes));
        w_.append(b);
    }

    // A cluster BLAS over the CLAS whose addresses the builds of info slots [first, first +
    // count) wrote to dstAddressesArray; its own info at kInfos + 0x800 is its one snapshot.
    void blas(uint32_t first, uint32_t count, uint64_t object_offset) {
        VkClusterAccelerationStructureClustersBottomLevelInputNV in{};
        in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
        in.maxTotalClusterCount = count;
        in.maxClusterCountPerAccelerationStructure = count;
        const VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV info{count, 8,
                                                                                kAddresses +
                                                                                    first * 8};
        other_op(tb::cluster_op_input(1, &in), object_offset, kInfos + 0x800,
                 tb::bytes_of(&info, 1));
    }

    // Moves the CLAS at kObjects + from_offset to kObjects + to_offset, overlap allowed (so
    // the source is retired: no object is left there) unless `no_overlap`, which leaves it.
    void move(uint64_t from_offset, uint64_t to_offset, bool no_overlap = false) {
        VkClusterAccelerationStructureMoveObjectsInputNV in{};
        in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
        in.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
        in.noMoveOverlap = no_overlap ? VK_TRUE : VK_FALSE;
        in.maxMovedBytes = sizes_.acceleration_structure_size;
        const VkClusterAccelerationStructureMoveObjectsInfoNV info{kObjects + from_offset};
        other_op(tb::cluster_op_input(1, &in), to_offset, kInfos + 0x900, tb::bytes_of(&info, 1));
    }

    void barrier(uint64_t src_stage, uint64_t src_access, uint64_t dst_stage, uint64_t dst_access) {
        w_.append(tb::memory_barrier(kCommandBuffer, src_stage, src_access, dst_stage, dst_access));
    }

    void update_vertices(const std::vector<float>& vertices) {
        fbs::CmdUpdateBufferT update;
        update.command_buffer = kCommandBuffer;
        update.dst_buffer = 0xb001;  // the vertex buffer
        update.data = tb::bytes_of(vertices);
        w_.append(update);
    }

    // Submits the command buffer `submissions` times, each waited for, and seals the file.
    void finish(uint32_t submissions = 1) {
        w_.end_and_submit(kQueue, kCommandBuffer, kFence);
        w_.wait_fence(kFence);
        for (uint32_t k = 1; k < submissions; ++k) {
            w_.append(
                tb::queue_submit(kQueue, {kCommandBuffer}, kFence, w_.next_submission_index()));
            w_.wait_fence(kFence);
        }
        w_.finish();
    }

    uint64_t scratch_size() const { return sizes_.build_scratch_size; }

private:
    static fbs::TraceHeaderT header() {
        fbs::TraceHeaderT h = tb::trace_header(tb::kEngineDriver, tb::kEngineDriver, "run ahead");
        h.device->cluster_properties =
            tb::cluster_properties(engine::EngineProperties::nvidia_default());
        return h;
    }
    VkClusterAccelerationStructureInputInfoNV input() const {
        return tb::cluster_op_input(1, &limits_);
    }
    // One op of `input`, its srcInfosArray entry at `info_at` (snapshot `info`), its object
    // at kObjects + object_offset, its address and size past the CLAS builds' slots.
    void other_op(const VkClusterAccelerationStructureInputInfoNV& input, uint64_t object_offset,
                  uint64_t info_at, const std::vector<uint8_t>& info) {
        auto commands = tb::cluster_commands(input);
        commands.dstImplicitData = kObjects + object_offset;
        commands.scratchData = kScratch;
        commands.dstAddressesArray = {kAddresses + 0x800 + (info_at - kInfos) / 8, 8, 8};
        commands.dstSizesArray = {kSizes + 0x800 + (info_at - kInfos) / 8, 4, 4};
        commands.srcInfosArray = {info_at, info.size(), info.size()};
        fbs::CmdBuildClusterAccelerationStructureIndirectT b =
            tb::cluster_build(kCommandBuffer, commands);
        b.inputs.push_back(w_.snapshot(info_at, info));
        w_.append(b);
    }

    tb::RecordWriter w_;
    VkClusterAccelerationStructureTriangleClusterInputNV limits_{};
    engine::BuildSizes sizes_;
};

// A digest of every region of replay memory after each cluster build.
class MemoryDigests : public replay::ReplayObserver {
public:
    void on_command(const replay::ReplayedCommand& c) override {
        if (!c.execution || !c.memory) return;
        size_t digest = 0;
        for (const auto& [base, region] : c.memory->regions()) {
            const std::string_view bytes(reinterpret_cast<const char*>(region.bytes.begin()),
                                         region.bytes.size());
            digest = digest * 31 + std::hash<std::string_view>{}(bytes) + base;
        }
        digests.push_back(digest);
    }
    std::vector<size_t> digests;
};

// The first 64 bytes at kObjects after each cluster command.
class ObjectBytes : public replay::ReplayObserver {
public:
    void on_command(const replay::ReplayedCommand& c) override {
        if (!c.execution || !c.memory) return;
        auto bytes = c.memory->read_bytes(kObjects, 64, {"test", -1});
        after.emplace_back(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    }
    std::vector<std::string> after;
};

struct Replayed {
    std::string json;
    std::vector<size_t> digests;
    replay::ReplayOptions::RunAheadCounts counts;
};

Replayed replay_with(const std::string& path, uint32_t threads) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return {};
    MemoryDigests observer;
    Replayed r;
    replay::ReplayOptions options;
    options.threads = threads;
    options.observer = &observer;
    options.run_ahead_counts = &r.counts;
    options.run_ahead = true;
    options.sync_model_thread = true;
    r.json = replay::to_json(replay::replay_trace(*reader, path, options)).dump(1);
    r.digests = observer.digests;
    return r;
}

// Build A; the transfer writes new vertices; build B reads them with only its first vertex in
// its snapshots (the rest it reads from the transfer's output).
void write_read_after_transfer(const std::string& path) {
    BuildsTrace t(path);
    t.build(0, grid(0, 0), 0, 0);
    t.barrier(kBuild, kAsWrite, VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT,
              VK_ACCESS_2_TRANSFER_WRITE_BIT);
    const std::vector<float> moved = grid(5, 1);
    t.update_vertices(moved);
    t.barrier(VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, kBuild,
              kAsRead | kAsWrite);
    t.build(0, moved, 1, 0x1000, {{kVertices, tb::bytes_of(moved.data(), 3)}});
    t.finish();
}

TEST(ReplayRunAhead, BuildReadingAnEarlierCommandsOutputOutsideItsSnapshotsRunsAgain) {
    const std::string path = temp_path("read_after_transfer.clt");
    write_read_after_transfer(path);
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(one.counts.started, 0u);  // one thread: every build in its turn
    EXPECT_EQ(many.counts.started, 2u);
    EXPECT_EQ(many.counts.stood, 1u);      // A read only its snapshots
    EXPECT_EQ(many.counts.run_again, 1u);  // B read the update's vertices
    ASSERT_EQ(one.digests.size(), 2u);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// A command buffer recorded once and submitted three times: the record stage's answers for its
// commands' snapshots go with the commands (session 15), so every execution lays the same bytes
// in; the first execution takes the runs started ahead, the later ones run in their turn.
TEST(ReplayRunAhead, ACommandBufferSubmittedAgainLaysTheSameSnapshotsIn) {
    const std::string path = temp_path("submitted_again.clt");
    {
        BuildsTrace t(path);
        t.build(0, grid(0, 0), 0, 0);
        t.build(0x400, grid(2, 1), 1, 0x1000);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.blas(0, 2, 0x4000);
        t.finish(3);
    }
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(many.counts.started, 3u);
    EXPECT_EQ(many.counts.stood, 3u);
    ASSERT_EQ(one.digests.size(), 9u);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// The test above has teeth: with commit's checks skipped, B's early run (on zero vertices where
// the update wrote) is taken and memory after it differs.
TEST(ReplayRunAhead, SkippingTheChecksTakesAStaleRun) {
    const std::string path = temp_path("stale_run.clt");
    write_read_after_transfer(path);
    const Replayed one = replay_with(path, 1);
    replay::detail::ClusterRunAhead::skip_checks_for_tests = true;
    const Replayed broken = replay_with(path, 4);
    replay::detail::ClusterRunAhead::skip_checks_for_tests = false;
    EXPECT_EQ(broken.counts.stood, 2u);
    ASSERT_EQ(broken.digests.size(), 2u);
    EXPECT_EQ(one.digests[0], broken.digests[0]);
    EXPECT_NE(one.digests[1], broken.digests[1]);
    std::remove(path.c_str());
}

// A and B write the same object bytes, dstAddressesArray/dstSizesArray elements and scratch:
// both stand (neither reads the other's output) and B's bytes are the ones left.
TEST(ReplayRunAhead, OverlappingWritesLandInQueueOrder) {
    const std::string path = temp_path("overlapping_writes.clt");
    {
        BuildsTrace t(path);
        t.build(0, grid(0, 0), 0, 0);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.build(512, grid(3, 2), 0, 0);  // same info slot, same destination
        t.finish();
    }
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(many.counts.started, 2u);
    EXPECT_EQ(many.counts.stood, 2u);
    ASSERT_EQ(one.digests.size(), 2u);
    EXPECT_NE(one.digests[0], one.digests[1]);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// Two CLAS builds and a BLAS over them (its cluster references are the addresses the CLAS
// builds wrote, outside its snapshots): all three run ahead and stand, the BLAS on the CLAS
// runs' bytes and objects.
TEST(ReplayRunAhead, BottomLevelBuildRunsOnTheClusterRunsBeforeIt) {
    const std::string path = temp_path("blas_over_runs.clt");
    {
        BuildsTrace t(path);
        t.build(0, grid(0, 0), 0, 0);
        t.build(512, grid(3, 2), 1, 0x1000);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.blas(0, 2, 0x10000);
        t.finish();
    }
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(many.counts.started, 3u);
    EXPECT_EQ(many.counts.stood, 3u);
    ASSERT_EQ(one.digests.size(), 3u);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    EXPECT_EQ(one.json.find("CLASTRACE-"), std::string::npos) << one.json;  // no finding
    std::remove(path.c_str());
}

// A move between the CLAS build and the BLAS retires the CLAS but leaves its bytes: the BLAS's
// run, which found the CLAS alive in its own directory, fails the directory check (not the byte
// comparison) and runs again, reporting the stale reference as one thread does.
TEST(ReplayRunAhead, BottomLevelBuildOverAMovedClusterRunsAgain) {
    const std::string path = temp_path("blas_after_move.clt");
    {
        BuildsTrace t(path);
        t.build(0, grid(0, 0), 0, 0);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.move(0, 0x8000);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.blas(0, 1, 0x10000);
        t.finish();
    }
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(many.counts.started, 2u);  // the CLAS build and the BLAS; the move (which
                                         // retires its source) in its turn
    EXPECT_EQ(many.counts.stood, 1u);
    EXPECT_EQ(many.counts.run_again, 1u);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    EXPECT_NE(one.json.find("moved away"), std::string::npos) << one.json;

    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    ASSERT_TRUE(reader) << error.message;
    ObjectBytes bytes;
    replay::ReplayOptions options;
    options.observer = &bytes;
    replay::replay_trace(*reader, path, options);
    ASSERT_EQ(bytes.after.size(), 3u);
    EXPECT_EQ(bytes.after[0], bytes.after[1]);  // the move left the CLAS's bytes as they were
    std::remove(path.c_str());
}

// Two CLAS builds, a BLAS over them, then a move (noMoveOverlap) of the first CLAS: the move
// runs ahead on the CLAS runs' bytes and objects, like the BLAS, and stands.
TEST(ReplayRunAhead, AMoveOfTheClustersJustBuiltRunsAheadAndStands) {
    const std::string path = temp_path("move_over_runs.clt");
    {
        BuildsTrace t(path);
        t.build(0, grid(0, 0), 0, 0);
        t.build(512, grid(3, 2), 1, 0x1000);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.blas(0, 2, 0x10000);
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.move(0, 0x8000, true);
        t.finish();
    }
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(many.counts.started, 4u);
    EXPECT_EQ(many.counts.stood, 4u);
    EXPECT_EQ(many.counts.run_again, 0u);
    ASSERT_EQ(one.digests.size(), 4u);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    EXPECT_EQ(one.json.find("CLASTRACE-"), std::string::npos) << one.json;  // no finding
    EXPECT_EQ(one.json.find("VUID-"), std::string::npos) << one.json;
    std::remove(path.c_str());
}

// The second build reads vertices a transfer wrote outside its snapshots, so its run holds a
// stale object; a move of that object started on it read the stale bytes: at its turn the
// byte comparison fails and the move runs again in place, as one thread runs it.
TEST(ReplayRunAhead, AMoveOfAStaleRunsObjectRunsAgain) {
    const std::string path = temp_path("move_of_stale.clt");
    {
        BuildsTrace t(path);
        t.build(0, grid(0, 0), 0, 0);
        t.barrier(kBuild, kAsWrite, VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT,
                  VK_ACCESS_2_TRANSFER_WRITE_BIT);
        const std::vector<float> moved = grid(5, 1);
        t.update_vertices(moved);
        t.barrier(VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, kBuild,
                  kAsRead | kAsWrite);
        t.build(0, moved, 1, 0x1000, {{kVertices, tb::bytes_of(moved.data(), 3)}});
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.move(0x1000, 0x8000, true);
        t.finish();
    }
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_EQ(many.counts.started, 3u);
    EXPECT_EQ(many.counts.stood, 1u);
    EXPECT_EQ(many.counts.run_again, 2u);  // the second build and the move
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// The replay bench's frames: CLAS builds (their reads all in their snapshots) run ahead across
// submissions and stand, and so do the BLAS builds and the moves (noMoveOverlap) over them.
TEST(ReplayRunAhead, ClusterFramesOfTheReplayBenchRunAheadAndStand) {
    const std::string path = bench_frames("bench_frames.clt", 5000);
    const Replayed one = replay_with(path, 1), many = replay_with(path, 4);
    EXPECT_GT(many.counts.started, 60u);  // 2 CLAS builds and a BLAS per frame, 24 frames
    EXPECT_EQ(many.counts.run_again, 0u);
    EXPECT_GE(many.counts.stood, many.counts.started - 3);  // the last frames may be left
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// A run gives its image back at its command's turn (a later BLAS run lays in only the bytes it
// wrote, kept apart), so however many frames the runs holding an image at once are at most the
// window's (4 x 8 threads) and the one being taken, and the BLAS runs still stand. Counted on the
// replay thread at each start and give-back, so the bound does not depend on the schedule.
TEST(ReplayRunAhead, TakenRunsGiveTheirImagesBackWhateverTheTraceLength) {
    const std::string path = bench_frames("long_frames.clt", 8000);
    const Replayed one = replay_with(path, 1), many = replay_with(path, 8);
    EXPECT_GE(many.counts.started, 300u);  // 100 frames, each a BLAS over two CLAS runs
    EXPECT_GE(many.counts.stood, many.counts.started - 3);
    EXPECT_GT(many.counts.most_images, 0u);
    EXPECT_LE(many.counts.most_images, 4u * 8u + 1u) << many.counts.most_images;
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// A BLAS run starts on the CLAS runs after the BLAS record before it, so once the next BLAS
// record is read (or the last one started) the runs before it are no longer kept: each frame's
// two CLAS runs, not the window's 32, while the BLAS runs still stand (before session 13 the
// window's capacity of them was kept, each with what it read and wrote).
TEST(ReplayRunAhead, OnlyTheBuildsABottomLevelRunMayStartOnAreKept) {
    const std::string path = bench_frames("kept_frames.clt", 8000);
    const Replayed one = replay_with(path, 1), many = replay_with(path, 8);
    EXPECT_GE(many.counts.stood, many.counts.started - 3);
    EXPECT_GE(many.counts.most_builds_kept, 2u);
    EXPECT_LE(many.counts.most_builds_kept, 4u) << many.counts.most_builds_kept;
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// The cluster commands of a trace: the bench's are CLAS builds, BLAS builds and moves that leave
// their sources (noMoveOverlap), all of which run ahead.
uint64_t builds_that_run_ahead(const std::string& path) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << error.message;
    uint64_t builds = 0;
    traces::RecordView view;
    while (reader && reader->next(&view)) {
        const auto* build = view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
        if (build && build->input()) ++builds;
    }
    return builds;
}

// The first 4096 records are read ahead before the replay binds any buffer, so no build among
// them can be planned then. They wait, in stream order, until regions are placed, and start
// before any build read after them: before, the window filled with later frames' runs and the
// first 200 frames' builds (585 of 3,741 at 10^5 ops on 16 threads) ran in their turn on the
// replay thread. 250 frames: longer than the records read ahead.
TEST(ReplayRunAhead, BuildsReadBeforeTheirBuffersAreBoundStillRunAhead) {
    const std::string path = bench_frames("unbound_frames.clt", 20000);
    const uint64_t builds = builds_that_run_ahead(path);
    EXPECT_GE(builds, 3u * 250u);
    const Replayed one = replay_with(path, 1), many = replay_with(path, 16);
    EXPECT_GE(many.counts.started, builds - 3) << builds;  // the last frames may be left
    EXPECT_EQ(many.counts.run_again, 0u);
    EXPECT_GE(many.counts.stood, many.counts.started - 3);
    EXPECT_EQ(one.digests, many.digests);
    EXPECT_EQ(one.json, many.json);
    std::remove(path.c_str());
}

// With runs ahead the sync model runs on its own thread unless CLASTRACE_REPLAY_SYNC_THREAD=0
// (the model's calls were the largest part of the replay thread's work left); asked for, it
// does without them; never on one thread or without hazards.
TEST(ReplayRunAhead, TheModelsThreadComesWithRunsAhead) {
    using replay::detail::model_on_own_thread;
    const char* kept = std::getenv("CLASTRACE_REPLAY_SYNC_THREAD");
    const std::string was = kept ? kept : "";
    unsetenv("CLASTRACE_REPLAY_SYNC_THREAD");
    replay::ReplayOptions options;
    options.threads = 4;
    EXPECT_TRUE(model_on_own_thread(options, true));
    EXPECT_FALSE(model_on_own_thread(options, false));
    options.sync_model_thread = true;
    EXPECT_TRUE(model_on_own_thread(options, false));
    options.sync_model_thread = false;
    setenv("CLASTRACE_REPLAY_SYNC_THREAD", "0", 1);
    EXPECT_FALSE(model_on_own_thread(options, true));
    setenv("CLASTRACE_REPLAY_SYNC_THREAD", "1", 1);
    EXPECT_TRUE(model_on_own_thread(options, false));
    options.threads = 1;
    EXPECT_FALSE(model_on_own_thread(options, true));
    options.threads = 4;
    options.check_hazards = false;
    EXPECT_FALSE(model_on_own_thread(options, true));
    if (kept)
        setenv("CLASTRACE_REPLAY_SYNC_THREAD", was.c_str(), 1);
    else
        unsetenv("CLASTRACE_REPLAY_SYNC_THREAD");
}

// Runs ahead are on by default from 2 threads (their state comes from the replay's pool, so
// their memory no longer grows with the trace's length), off with CLASTRACE_REPLAY_RUN_AHEAD=0
// or ReplayOptions::run_ahead = false, and never on one thread.
TEST(ReplayRunAhead, OnByDefaultFromTwoThreadsAndOffWhenAsked) {
    const std::string path = bench_frames("default_frames.clt", 1000);
    auto started = [&](uint32_t threads, bool asked = true) {
        traces::TraceError error;
        auto reader = traces::TraceReader::open(path, &error);
        EXPECT_TRUE(reader) << error.message;
        if (!reader) return uint64_t(0);
        replay::ReplayOptions::RunAheadCounts counts;
        replay::ReplayOptions options;
        options.threads = threads;
        options.run_ahead = asked;
        options.run_ahead_counts = &counts;
        replay::replay_trace(*reader, path, options);
        return counts.started;
    };
    const char* kept = std::getenv("CLASTRACE_REPLAY_RUN_AHEAD");
    const std::string was = kept ? kept : "";
    unsetenv("CLASTRACE_REPLAY_RUN_AHEAD");
    EXPECT_GT(started(2), 0u);
    EXPECT_GT(started(16), 0u);
    EXPECT_EQ(started(1), 0u);
    EXPECT_EQ(started(4, false), 0u);
    setenv("CLASTRACE_REPLAY_RUN_AHEAD", "0", 1);
    EXPECT_EQ(started(4), 0u);
    setenv("CLASTRACE_REPLAY_RUN_AHEAD", "1", 1);
    EXPECT_GT(started(2, false), 0u);
    EXPECT_EQ(started(1), 0u);
    if (kept)
        setenv("CLASTRACE_REPLAY_RUN_AHEAD", was.c_str(), 1);
    else
        unsetenv("CLASTRACE_REPLAY_RUN_AHEAD");
    std::remove(path.c_str());
}

}  // namespace
