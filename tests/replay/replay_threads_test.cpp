// SPDX-License-Identifier: Apache-2.0
// Replay on several threads reports exactly what replay on one thread reports: every shipped
// sample trace and traces of every generator (the replay bench's cluster frames, the consumer
// bench's ray-traced frames, valid and damaged random streams) replayed with 1 and 4 threads,
// their JSON reports compared as text. With 2 and more threads the sync model runs on a thread of
// its own (sync_model_feed.h): the feed alone against the model called inline, an observer's
// per-command log, and a sparse trace (the model inline from its first bind) are checked too; so
// are runs ahead on a single worker (the replay thread runs those not started by their turn)
// and the pool their images' bytes come from.
#include "catalogue_replay.h"
#include "cluster_speculation.h"
#include "random_stream.h"
#include "replay_bench_trace.h"
#include "replayer_record_stage.h"
#include "rt_frame_bench_trace.h"
#include "sync_model_feed.h"

#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <utility>
#include <vector>
#include <sys/wait.h>
#include <unistd.h>

using namespace clastrace;

namespace {

constexpr uint32_t kManyThreads = 4;

std::string temp_path(const std::string& name) {
    return (std::filesystem::temp_directory_path() /
            ("replay_threads_" + std::to_string(::getpid()) + "_" + name))
        .string();
}

// The replay's JSON report with `threads` threads (what `clastrace replay --json` prints).
std::string replay_json(const std::string& path, uint32_t threads, bool hazards = true,
                        replay::ReplayObserver* observer = nullptr,
                        replay::ReplayOptions::RunAheadCounts* run_ahead = nullptr) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << path << ": " << error.message;
    if (!reader) return {};
    replay::ReplayOptions options;
    options.threads = threads;
    options.check_hazards = hazards;
    options.observer = observer;
    options.run_ahead_counts = run_ahead;
    options.sync_model_thread = options.run_ahead = true;  // (what more threads may change)
    EXPECT_EQ(replay::replay_threads(options), threads);
    return replay::to_json(replay::replay_trace(*reader, path, options)).dump(1);
}

// The first line where two reports differ, for a readable failure.
std::string first_difference(const std::string& a, const std::string& b) {
    size_t line = 1, at = 0;
    while (at < a.size() && at < b.size() && a[at] == b[at])
        if (a[at++] == '\n') ++line;
    const size_t start = a.rfind('\n', at) == std::string::npos ? 0 : a.rfind('\n', at) + 1;
    return "line " + std::to_string(line) + ": 1 thread: " + a.substr(start, 160) + "\n" +
           std::to_string(kManyThreads) + " threads: " + b.substr(start, 160);
}

void expect_same_report(const std::string& path, bool hazards = true) {
    const std::string one = replay_json(path, 1, hazards);
    const std::string many = replay_json(path, kManyThreads, hazards);
    ASSERT_FALSE(one.empty());
    EXPECT_TRUE(one == many) << path << "\n" << first_difference(one, many);
}

TEST(ReplayThreads, EveryShippedSampleReportsTheSameOnOneAndManyThreads) {
    size_t samples = 0;
    for (const auto& entry : std::filesystem::directory_iterator(CLASTRACE_SAMPLES_DIR)) {
        if (entry.path().extension() != ".clt") continue;
        ++samples;
        SCOPED_TRACE(entry.path().string());
        expect_same_report(entry.path().string());
    }
    EXPECT_GE(samples, 4u);
}

TEST(ReplayThreads, ClusterFramesOfTheReplayBenchReportTheSame) {
    const std::string path = temp_path("bench_frames.clt");
    bench::BenchTraceShape shape;
    shape.target_ops = 20000;
    shape.clusters_per_build = 96;  // wide enough for the ops to spread over the threads
    bench::write_bench_trace(path, shape);
    expect_same_report(path, true);
    expect_same_report(path, false);
    std::remove(path.c_str());
}

// The record stage (replayer_record_stage.h) hands out the records a reader of its own hands
// out, in order and byte for byte, with, for the snapshots a record names, the bytes
// read_contents answers, in the order the record names them (find_answer finds each at its
// cursor), even while the test asks its reader between records as the replay thread does.
TEST(ReplayThreads, TheRecordStageHandsOutTheReadersRecordsAndAnswers) {
    const std::string path = temp_path("stage_frames.clt");
    bench::BenchTraceShape shape;
    shape.target_ops = 4000;
    bench::write_bench_trace(path, shape);
    traces::TraceError error;
    auto staged_reader = traces::TraceReader::open(path, &error);
    auto reference = traces::TraceReader::open(path, &error);
    ASSERT_TRUE(staged_reader && reference) << error.message;
    std::mutex reader_mutex;
    replay::detail::RecordStage stage(*staged_reader, reader_mutex);
    uint64_t records = 0, resolved = 0;
    replay::detail::StagedRecord r;
    traces::RecordView view;
    std::vector<uint8_t> bytes;
    while (stage.next(&r)) {
        ASSERT_TRUE(reference->next(&view)) << "record " << records;
        ASSERT_EQ(r.view.size, view.size) << "record " << records;
        ASSERT_EQ(std::vector<uint8_t>(r.view.bytes, r.view.bytes + r.view.size),
                  std::vector<uint8_t>(view.bytes, view.bytes + view.size));
        const traces::SnapshotLists lists = traces::record_snapshots(*view.record);
        size_t cursor = 0, named = 0;
        uint64_t bytes_answered = 0;
        for (const traces::SnapshotVector* list : {lists.inputs, lists.outputs})
            for (size_t i = 0; list && i < list->size(); ++i, ++named) {
                const size_t at = cursor;
                const auto* answer =
                    replay::detail::find_answer(r.resolved, &cursor, list->Get(i)->hash());
                ASSERT_TRUE(answer) << "record " << records << " snapshot " << named;
                EXPECT_EQ(cursor, at + 1);  // in order: found where the cursor was
                bytes_answered += (*answer)->size();
            }
        EXPECT_EQ(named, r.resolved.size());
        EXPECT_EQ(bytes_answered, r.resolved_bytes);
        {
            std::lock_guard lock(reader_mutex);  // the replay thread's calls meanwhile
            for (const auto& [hash, kept] : r.resolved) {
                ASSERT_FALSE(staged_reader->read_contents(hash, &bytes));
                EXPECT_EQ(*kept, bytes);
                ASSERT_FALSE(reference->read_contents(hash, &bytes));
                EXPECT_EQ(*kept, bytes);
                ++resolved;
            }
        }
        ++records;
    }
    EXPECT_FALSE(reference->next(&view));
    EXPECT_GT(resolved, records / 4);
    std::remove(path.c_str());
}

// Two threads: one worker, which the replay thread often overtakes; a run no worker has started
// by its command's turn runs on the replay thread, and stands or not as on a worker.
TEST(ReplayThreads, ClusterFramesOnOneWorkerReportTheSameAndTheirRunsStand) {
    const std::string path = temp_path("bench_frames_one_worker.clt");
    bench::BenchTraceShape shape;
    shape.target_ops = 10000;
    bench::write_bench_trace(path, shape);
    replay::ReplayOptions::RunAheadCounts counts;
    const std::string one = replay_json(path, 1);
    const std::string two = replay_json(path, 2, true, nullptr, &counts);
    EXPECT_TRUE(one == two) << first_difference(one, two);
    EXPECT_GT(counts.started, 200u);
    EXPECT_EQ(counts.run_again, 0u);
    EXPECT_GE(counts.stood, counts.started - 2);  // the last frames may be left
    std::remove(path.c_str());
}

// With hazards checked, a cluster command's run ahead makes the accesses the sync model takes
// (the scratch at the driver's answered size among them) on its worker: the hazards they give
// are the ones of one thread, where the command's turn makes them.
TEST(ReplayThreads, HazardsFromTheAccessesRunsAheadMadeAreTheOneThreadsOnes) {
    const std::string path = temp_path("bench_frames_no_scratch_barrier.clt");
    bench::BenchTraceShape shape;
    shape.target_ops = 4000;
    shape.scratch_barriers = false;
    bench::write_bench_trace(path, shape);
    replay::ReplayOptions::RunAheadCounts counts;
    const std::string one = replay_json(path, 1);
    const std::string many = replay_json(path, kManyThreads, true, nullptr, &counts);
    EXPECT_TRUE(one == many) << first_difference(one, many);
    const nlohmann::json report = nlohmann::json::parse(many);
    ASSERT_FALSE(report["hazards"].empty());
    EXPECT_NE(many.find("-byte buildScratchSize"), std::string::npos);  // the sized scratch
    EXPECT_GT(counts.stood, 0u);
    EXPECT_EQ(counts.run_again, 0u);
    std::remove(path.c_str());
}

TEST(ReplayThreads, RayTracedFramesOfTheConsumerBenchReportTheSame) {
    const std::string path = temp_path("rt_frames.clt");
    bench::RtFrameShape shape;
    shape.frames = 4;
    shape.triangles_per_mesh = 40000;  // tree builds past the engine's parallel split size
    bench::write_rt_frame_trace(path, shape);
    expect_same_report(path);
    std::remove(path.c_str());
}

// Damaged streams carry findings and hazards of every kind: their text and order must match too.
TEST(ReplayThreads, ValidAndDamagedRandomStreamsReportTheSame) {
    for (double mutation_rate : {0.0, 0.2}) {
        const std::string path = temp_path("stream.clt");
        test::RandomStreamOptions o;
        o.seed = 11;
        o.min_cluster_ops = 4000;
        o.mutation_rate = mutation_rate;
        test::write_random_stream(path, o);
        SCOPED_TRACE("mutation rate " + std::to_string(mutation_rate));
        expect_same_report(path);
        if (mutation_rate > 0) {
            const std::string one = replay_json(path, 1);
            const auto report = nlohmann::json::parse(one);
            EXPECT_FALSE(report["findings"].empty());  // the comparison covered findings
            EXPECT_FALSE(report["hazards"].empty());   // and hazards
        }
        std::remove(path.c_str());
    }
}

TEST(ReplayThreads, ZeroThreadsMeansTheMachinesCores) {
    replay::ReplayOptions options;
    options.threads = 0;
    EXPECT_GE(replay::replay_threads(options), 1u);
    options.threads = 3;
    EXPECT_EQ(replay::replay_threads(options), 3u);
}

// `clastrace replay --threads`: the CLI passes the count on and prints the same JSON.
TEST(ReplayThreads, CommandLineThreadsPrintTheSameJson) {
    auto run = [](const std::string& threads) {
        const std::string out = temp_path("cli_" + threads + ".json");
        const std::string command = std::string(CLASTRACE_BIN) + " replay --json --threads " +
                                    threads + " " + CLASTRACE_SAMPLES_DIR + "/sample.clt > " + out +
                                    " 2>/dev/null";
        const int status = std::system(command.c_str());
        std::FILE* f = std::fopen(out.c_str(), "rb");
        std::string text;
        if (f) {
            char buffer[4096];
            for (size_t n; (n = std::fread(buffer, 1, sizeof buffer, f)) > 0;)
                text.append(buffer, n);
            std::fclose(f);
        }
        std::remove(out.c_str());
        return std::make_pair(status, text);
    };
    const auto one = run("1"), many = run(std::to_string(kManyThreads));
    EXPECT_NE(one.second.find("\"findings\""), std::string::npos);
    EXPECT_EQ(one.first, many.first);
    EXPECT_EQ(one.second, many.second);
    const auto refused = run("0");
    EXPECT_EQ(WEXITSTATUS(refused.first), 2);  // a usage error
}

// --- runs ahead: their images' bytes (cluster_speculation.h) ------------------------------

// A record's answers are looked up from a cursor that moves past each one found, and wraps:
// snapshots asked for in the record's order cost one comparison each.
TEST(SnapshotAnswers, AreFoundFromTheCursorOnThenFromTheStart) {
    using replay::detail::find_answer;
    using replay::detail::SnapshotAnswer;
    auto bytes = [](uint8_t v) { return std::make_shared<const std::vector<uint8_t>>(3, v); };
    const std::vector<SnapshotAnswer> answers{{7, bytes(1)}, {9, bytes(2)}, {7, bytes(3)}};
    size_t cursor = 0;
    ASSERT_TRUE(find_answer(answers, &cursor, 9));
    EXPECT_EQ(cursor, 2u);
    const auto* second_seven = find_answer(answers, &cursor, 7);  // from the cursor on
    ASSERT_TRUE(second_seven);
    EXPECT_EQ((**second_seven)[0], 3);
    EXPECT_EQ(cursor, 3u);
    const auto* wrapped = find_answer(answers, &cursor, 9);  // past the end: from the start
    ASSERT_TRUE(wrapped);
    EXPECT_EQ((**wrapped)[0], 2);
    EXPECT_FALSE(find_answer(answers, &cursor, 8));
    EXPECT_EQ(cursor, 2u);  // a miss leaves it
    size_t none = 0;
    EXPECT_FALSE(find_answer({}, &none, 7));
}

TEST(ImageStoragePool, HandsBackTheBytesItWasGivenForTheSameSizeOnly) {
    replay::detail::ImageStoragePool pool;
    constexpr uint64_t kSize = 3 * engine::RegionBytes::kPageBytes + 5;
    engine::RegionBytes first = pool.take(kSize);
    ASSERT_EQ(first.size(), kSize);
    first.write_at(engine::RegionBytes::kPageBytes, 1)[0] = std::byte{0x5a};
    const std::byte* mapped = std::as_const(first).data();
    std::vector<engine::RegionBytes> given;
    given.push_back(std::move(first));
    pool.give(std::move(given));
    const engine::RegionBytes other = pool.take(kSize + 1);  // another size: new zeros
    EXPECT_NE(std::as_const(other).data(), mapped);
    EXPECT_EQ(other[engine::RegionBytes::kPageBytes], std::byte{0});
    const engine::RegionBytes again = pool.take(kSize);
    EXPECT_EQ(std::as_const(again).data(), mapped);  // no new mapping
    EXPECT_EQ(again[engine::RegionBytes::kPageBytes], std::byte{0x5a});
    EXPECT_EQ(again.resident_bytes(), engine::RegionBytes::kPageBytes);
    const engine::RegionBytes fresh = pool.take(kSize);  // the one kept is taken
    EXPECT_NE(std::as_const(fresh).data(), mapped);
}

// --- the sync model on its own thread (sync_model_feed.h) ----------------------------------

// Records on which thread the model resolves addresses: every access and buffer barrier asks.
struct ThreadOfModel : replay::AddressResolver {
    std::thread::id seen;
    bool resolve(replay::AddressRange, std::vector<replay::ResolvedRange>*) override {
        seen = std::this_thread::get_id();
        return false;
    }
};

// Accesses that hold their field's text, scribbled over when they are freed: a feed that let
// them go before the model applied the call would hand it other names.
struct OwnedAccesses {
    std::string text;
    std::vector<replay::Access> accesses;
    ~OwnedAccesses() {
        for (volatile char& c : text) c = 'X';
    }
};

// A stream of accesses, barriers, submissions and host waits over a few hundred bytes, with
// hazards of every class; each field's text is overwritten right after the call, so a feed that
// kept only the caller's view would hand the model other names, and a third of the accesses come
// with an owner of their text that the caller lets go right after the call.
std::vector<std::string> feed_stream(replay::detail::SyncModelFeed& feed) {
    using namespace replay;
    std::mt19937 random(7);
    auto pick = [&random](uint32_t n) { return uint32_t(random() % n); };
    const StageMask stages[] = {VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                VK_PIPELINE_STAGE_2_COPY_BIT,
                                VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT};
    const AccessMask reads[] = {VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR,
                                VK_ACCESS_2_TRANSFER_READ_BIT, VK_ACCESS_2_SHADER_READ_BIT};
    const AccessMask writes[] = {VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                                 VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_ACCESS_2_SHADER_WRITE_BIT};
    std::string field;
    uint32_t submission = 0;
    for (uint32_t batch = 0; batch < 60; ++batch) {
        const QueueId queue = pick(2);
        feed.begin_submission(queue, submission);
        for (uint32_t command = 0; command < 40; ++command) {
            const CommandRef ref{submission, 0, 0xC0, command, "vkCmdTest"};
            const uint32_t kind = pick(3);
            if (pick(8) == 0) {
                const MemoryBarrier barrier{stages[kind], writes[kind], stages[pick(3)],
                                            reads[pick(3)] | writes[pick(3)]};
                feed.pipeline_barrier(ref, DependencyInfo{std::span(&barrier, 1), {}, 0});
                continue;
            }
            const uint64_t begin = uint64_t(pick(32)) * 16;
            const bool write = pick(2) == 0;
            field = (write ? "dst[" : "src[") + std::to_string(command) + "] of a long name";
            if (command % 16 == 5) field += std::string(5000, '.');  // past the feed's blocks
            std::vector<Access> accesses{{{begin, begin + 16 + pick(64)},
                                          stages[kind],
                                          write ? writes[kind] : reads[kind],
                                          write,
                                          field}};
            const uint32_t how = pick(3);
            if (how == 0) {
                feed.record_accesses(ref, accesses);
            } else if (how == 1) {
                feed.record_access(ref, accesses[0]);
            } else {
                auto owned = std::make_shared<OwnedAccesses>();
                owned->text = field;
                owned->accesses = accesses;
                owned->accesses[0].field = owned->text;
                feed.record_accesses(ref, owned->accesses, owned);
            }
            field.assign(field.size(), 'X');
        }
        feed.end_submission({}, 100 + batch);
        if (pick(3) == 0) feed.wait_for_fence(100 + batch);
        ++submission;
    }
    std::vector<std::string> texts;
    for (const HazardReport& h : feed.hazards()) texts.push_back(h.format());
    texts.push_back("accesses " + std::to_string(feed.stats().accesses) + ", barriers " +
                    std::to_string(feed.stats().barriers));
    return texts;
}

TEST(SyncModelFeed, ItsThreadGivesTheHazardsOfTheModelCalledInline) {
    ThreadOfModel inline_thread, own_thread;
    replay::SyncModel inline_model, threaded_model;
    inline_model.set_address_resolver(&inline_thread, {});
    threaded_model.set_address_resolver(&own_thread, {});
    replay::detail::SyncModelFeed inline_feed(inline_model), threaded_feed(threaded_model);
    threaded_feed.start_thread();
    ASSERT_TRUE(threaded_feed.threaded());
    const std::vector<std::string> expected = feed_stream(inline_feed);
    const std::vector<std::string> got = feed_stream(threaded_feed);
    ASSERT_GT(expected.size(), 20u);  // the stream has hazards to compare
    EXPECT_EQ(got, expected);
    EXPECT_EQ(inline_thread.seen, std::this_thread::get_id());
    EXPECT_NE(own_thread.seen, std::this_thread::get_id());  // the model ran on its own thread
    threaded_feed.stop_thread();
    EXPECT_FALSE(threaded_feed.threaded());
}

// An observer reads the model after every command (that command's hazards): the read drains the
// model's queue, so each command's hazards still follow it, on any number of threads.
struct HazardsByCommand : replay::ReplayObserver {
    std::string log;
    void on_command(const replay::ReplayedCommand& c) override {
        log += "command " + std::to_string(c.where.sequence) + "\n";
    }
    void on_finding(const replay::ReplayFinding& f) override { log += f.format() + "\n"; }
    void on_hazard(const replay::HazardReport& h) override { log += h.format() + "\n"; }
};

TEST(ReplayThreads, AnObserverSeesEachCommandsHazardsRightAfterItOnManyThreads) {
    const std::string path = temp_path("observed.clt");
    test::RandomStreamOptions o;
    o.seed = 5;
    o.min_cluster_ops = 2000;
    o.mutation_rate = 0.2;
    test::write_random_stream(path, o);
    HazardsByCommand one, many;
    replay_json(path, 1, true, &one);
    replay_json(path, kManyThreads, true, &many);
    EXPECT_NE(one.log.find("HAZARD"), std::string::npos) << one.log.substr(0, 2000);
    EXPECT_TRUE(one.log == many.log) << first_difference(one.log, many.log);
    std::remove(path.c_str());
}

// From a trace's first sparse bind the model resolves addresses through the binds and reports
// unbound parts as findings, so it runs inline from there: the build's unbound-page finding
// (the model's) comes before the later bind's overlap finding (the replay's), as on one thread.
TEST(ReplayThreads, SparseBindsKeepTheModelsFindingsInTraceOrder) {
    using namespace test::catalogue;
    constexpr uint64_t kSparse = 0xd001, kSparseAddress = 0x50000000, kPage = 0x10000;
    constexpr uint64_t kQueue = 0x7001, kMemory = 0x1001;
    const std::string path = temp_path("sparse.clt");
    {
        test::TraceScript t(path, device());
        add_buffers(t);
        t.sparse_buffer(kSparse, 2 * kPage,
                        VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT |
                            VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
                            VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR);
        // Only the second page is bound: the build writes the first.
        t.bind_sparse(kQueue, kSparse, kSparseAddress,
                      {{kPage, kPage, VkDeviceMemory(kMemory), kDst - kBase + kPage, 0}});
        ClusterCommand c = triangle_clusters(Destinations::kImplicit);
        c.info.dstImplicitData = kSparseAddress;
        c.emit(t);
        t.submit(kQueue);
        t.device_wait_idle();
        // One range bound twice in one batch: a finding of the replay itself.
        t.bind_sparse(kQueue, kSparse, kSparseAddress,
                      {{0, kPage, VkDeviceMemory(kMemory), kDst - kBase, 0},
                       {0, kPage, VkDeviceMemory(kMemory), kDst - kBase, 0}});
        t.finish();
    }
    const std::string one = replay_json(path, 1);
    const size_t unbound = one.find("CLASTRACE-sparse-unbound-access"),
                 overlap = one.find("CLASTRACE-sparse-bind-overlap");
    ASSERT_NE(unbound, std::string::npos) << one;
    ASSERT_NE(overlap, std::string::npos) << one;
    EXPECT_LT(unbound, overlap);
    expect_same_report(path);
    std::remove(path.c_str());
}

}  // namespace
