// SPDX-License-Identifier: Apache-2.0
// Long random streams: correctly synchronized ones must replay with no finding and no
// hazard; damaged ones (dropped dependencies, hostile infos/counts/strides/addresses,
// flipped file bytes) must replay to the end with well-formed findings, never crash.
#include "random_stream.h"
#include "trace_files.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <unistd.h>

namespace {

using namespace clastrace;

std::string temp_path(const std::string& name) {
    return test::temp_trace_path("random_stream", name);
}

replay::ReplayReport replay_file(const std::string& path) {
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    if (!reader) return {};
    return replay::replay_trace(*reader, path);
}

bool well_formed(const replay::ReplayFinding& f) {
    const std::string& r = f.rule;
    return (r.rfind("VUID-", 0) == 0 || r.rfind("CLASTRACE-", 0) == 0) && !f.message.empty() &&
           !f.format().empty();
}

TEST(RandomStreams, TenThousandOpsOfValidStreamReplayWithoutFindingOrHazard) {
    for (uint64_t seed : {1u, 2u}) {
        const std::string path = temp_path("valid_" + std::to_string(seed) + ".clt");
        test::RandomStreamOptions o;
        o.seed = seed;
        const test::RandomStreamStats written = test::write_random_stream(path, o);
        ASSERT_GE(written.cluster_ops, 10000u);
        for (uint64_t n : written.commands_by_op_type) EXPECT_GT(n, 0u);  // every op type
        EXPECT_GT(written.events, 0u);
        EXPECT_GT(written.narrow_signals, 0u);
        EXPECT_GT(written.semaphores, written.narrow_signals);
        EXPECT_GT(written.host_writes, 0u);
        EXPECT_GT(written.submissions, 50u);
        EXPECT_GT(written.command_buffers, 50u);
        const replay::ReplayReport r = replay_file(path);
        std::remove(path.c_str());
        EXPECT_TRUE(r.findings.empty()) << replay::format_text(r).substr(0, 4000);
        EXPECT_TRUE(r.hazards.empty()) << replay::format_text(r).substr(0, 4000);
        EXPECT_TRUE(r.trace_damage.empty());
        EXPECT_EQ(r.counts.cluster_commands, written.cluster_commands);
        EXPECT_EQ(r.counts.cluster_ops, written.cluster_ops);
        EXPECT_EQ(r.counts.submissions, written.submissions);
        EXPECT_GT(r.counts.barriers, written.cluster_commands / 2);
        EXPECT_GT(r.counts.accesses, 6 * written.cluster_ops);
    }
}

TEST(RandomStreams, MutatedStreamsReplayToTheEndWithWellFormedFindings) {
    uint64_t hazards = 0, findings = 0;
    for (uint64_t seed = 100; seed < 112; ++seed) {
        const std::string path = temp_path("mutant_" + std::to_string(seed) + ".clt");
        test::RandomStreamOptions o;
        o.seed = seed;
        o.min_cluster_ops = 600;
        o.mutation_rate = 0.1;
        const test::RandomStreamStats written = test::write_random_stream(path, o);
        EXPECT_GT(written.mutations, 0u);
        const replay::ReplayReport r = replay_file(path);
        std::remove(path.c_str());
        EXPECT_EQ(r.counts.submissions, written.submissions);  // the replay reached the end
        for (const replay::ReplayFinding& f : r.findings) EXPECT_TRUE(well_formed(f)) << f.format();
        for (const replay::HazardReport& h : r.hazards) EXPECT_FALSE(h.format().empty());
        hazards += r.hazards.size();
        findings += r.findings.size();
    }
    EXPECT_GT(hazards, 0u);   // dropped dependencies were found
    EXPECT_GT(findings, 0u);  // damaged commands were found
}

TEST(RandomStreams, FlippedBytesOfAStreamFileNeverCrash) {
    const std::string clean = temp_path("flip_src.clt");
    test::RandomStreamOptions o;
    o.seed = 7;
    o.min_cluster_ops = 300;
    test::write_random_stream(clean, o);
    std::ifstream in(clean, std::ios::binary);
    const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), {});
    std::remove(clean.c_str());
    ASSERT_GT(bytes.size(), 1000u);
    std::mt19937_64 rng(8);
    const std::string path = temp_path("flip.clt");
    for (int round = 0; round < 30; ++round) {
        std::vector<char> mutant = bytes;
        for (int k = 0, n = 1 + int(rng() % 6); k < n; ++k)
            mutant[rng() % mutant.size()] ^= char(1 << (rng() % 8));
        std::ofstream(path, std::ios::binary).write(mutant.data(), std::streamsize(mutant.size()));
        const replay::ReplayReport r = replay_file(path);
        for (const replay::ReplayFinding& f : r.findings) EXPECT_TRUE(well_formed(f)) << f.format();
    }
    std::remove(path.c_str());
}

}  // namespace

// More seeds, run on request (CLASTRACE_STREAM_SEEDS=N): a search for false positives.
TEST(RandomStreams, ManySeedsOnRequest) {
    const char* env = std::getenv("CLASTRACE_STREAM_SEEDS");
    if (!env) GTEST_SKIP() << "set CLASTRACE_STREAM_SEEDS=N to replay N more valid streams";
    const int seeds = std::atoi(env);
    for (int seed = 1000; seed < 1000 + seeds; ++seed) {
        const std::string path = temp_path("seed_" + std::to_string(seed) + ".clt");
        test::RandomStreamOptions o;
        o.seed = uint64_t(seed);
        o.min_cluster_ops = 3000;
        o.queues = 1 + uint32_t(seed % 4);
        test::write_random_stream(path, o);
        const replay::ReplayReport r = replay_file(path);
        std::remove(path.c_str());
        EXPECT_TRUE(r.clean()) << "seed " << seed << "\n" << replay::format_text(r).substr(0, 3000);
        o.mutation_rate = 0.2;  // and a damaged twin: must replay to the end
        o.min_cluster_ops = 800;
        const test::RandomStreamStats written = test::write_random_stream(path, o);
        const replay::ReplayReport m = replay_file(path);
        std::remove(path.c_str());
        EXPECT_EQ(m.counts.submissions, written.submissions) << "seed " << seed;
    }
}
