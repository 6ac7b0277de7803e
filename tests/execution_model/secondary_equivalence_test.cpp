// SPDX-License-Identifier: Apache-2.0
// Random command streams replayed twice: once with runs of commands moved into secondary
// command buffers (executed in place by vkCmdExecuteCommands), once all in the primary. A
// secondary's commands are part of the primary's command-buffer order, so both must give the
// same hazards (class, commands, fields, overlap), the same engine runs and the same findings.
#include "catalogue_scene.h"
#include "trace_script.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <tuple>
#include <unistd.h>
#include <vector>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

enum class Op { kCopyInfos, kFillOutputs, kBuild, kFullBarrier, kCopyToBuildBarrier };

struct Runs : replay::ReplayObserver {
    std::vector<uint32_t> op_counts;
    void on_command(const replay::ReplayedCommand& c) override {
        if (c.execution &&
            c.record->body_type() == fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect)
            op_counts.push_back(c.execution->op_count);
    }
};

void emit(TraceScript& t, Op op) {
    static const std::vector<uint8_t> infos =
        bytes_of(std::vector<TriangleInfo>{triangle_info(0), triangle_info(1)});
    switch (op) {
    case Op::kCopyInfos:
        t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});
        break;
    case Op::kFillOutputs: t.fill(kOutBuffer, 0, 64, 0); break;
    case Op::kBuild: triangle_clusters(Destinations::kImplicit).emit(t); break;
    case Op::kFullBarrier: t.full_barrier(); break;
    case Op::kCopyToBuildBarrier:
        t.barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                  VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                  VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
        break;
    }
}

// `secondary[i]`: 0 for a command of the primary, else the secondary (1, 2, ...) holding it;
// consecutive commands of one secondary are recorded together, consecutive secondaries run
// from one vkCmdExecuteCommands. With `nested` false everything goes into the primary.
void write(const std::string& path, const std::vector<Op>& ops,
           const std::vector<uint32_t>& secondary, bool nested) {
    TraceScript t(path, device());
    add_buffers(t);
    constexpr uint64_t kPrimary = 0xc100, kSecondaryBase = 0x5c00;
    if (nested)
        for (size_t i = 0; i < ops.size();) {
            if (!secondary[i]) {
                ++i;
                continue;
            }
            t.begin(kSecondaryBase + secondary[i], 0, 1, 0);
            const uint32_t s = secondary[i];
            for (; i < ops.size() && secondary[i] == s; ++i) emit(t, ops[i]);
            t.end();
        }
    t.begin(kPrimary, 0, 0, 0);
    for (size_t i = 0; i < ops.size();) {
        if (!nested || !secondary[i]) {
            emit(t, ops[i++]);
            continue;
        }
        std::vector<uint64_t> run;
        for (; i < ops.size() && secondary[i]; ++i)
            if (run.empty() || run.back() != kSecondaryBase + secondary[i])
                run.push_back(kSecondaryBase + secondary[i]);
        t.execute_commands(run);
    }
    t.end();
    t.submit_listed(0x9001, {kPrimary});
    t.finish();
}

struct Outcome {
    std::vector<
        std::tuple<int, std::string, std::string, std::string, std::string, uint64_t, uint64_t>>
        hazards;
    std::vector<uint32_t> op_counts;
    std::vector<std::string> rules;
};

Outcome replay_of(const std::string& path) {
    Outcome o;
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    EXPECT_TRUE(reader) << e.message;
    if (!reader) return o;
    Runs runs;
    replay::ReplayOptions options;
    options.observer = &runs;
    replay::ReplayReport r = replay::replay_trace(*reader, path, options);
    for (const auto& h : r.hazards)
        o.hazards.emplace_back(int(h.hazard), h.prior.command.name, h.later.command.name,
                               h.prior.field, h.later.field, h.overlap.begin, h.overlap.end);
    for (const auto& f : r.findings) o.rules.push_back(f.rule);
    o.op_counts = runs.op_counts;
    std::remove(path.c_str());
    return o;
}

TEST(SecondaryEquivalence, RandomStreamsMatchTheirFlattenedTwin) {
    size_t with_hazards = 0, with_secondaries = 0;
    for (uint32_t seed = 1; seed <= 60; ++seed) {
        SCOPED_TRACE("seed " + std::to_string(seed));
        std::mt19937 rng(seed);
        const size_t n = 6 + rng() % 10;
        std::vector<Op> ops;
        std::vector<uint32_t> secondary;
        uint32_t current = 0, next = 1;
        for (size_t i = 0; i < n; ++i) {
            ops.push_back(Op(rng() % 5));
            if (rng() % 3 == 0) current = rng() % 2 ? 0 : next++;  // switch primary/new secondary
            secondary.push_back(current);
        }
        const std::string base =
            (std::filesystem::temp_directory_path() /
             ("secondary_equivalence_" + std::to_string(::getpid()) + "_" + std::to_string(seed)))
                .string();
        write(base + "_nested.clt", ops, secondary, true);
        write(base + "_flat.clt", ops, secondary, false);
        const Outcome nested = replay_of(base + "_nested.clt");
        const Outcome flat = replay_of(base + "_flat.clt");
        EXPECT_EQ(nested.hazards, flat.hazards);
        EXPECT_EQ(nested.op_counts, flat.op_counts);
        EXPECT_EQ(nested.rules, flat.rules);
        with_hazards += !flat.hazards.empty();
        with_secondaries += next > 1;
    }
    // The streams exercise both outcomes, and most of them use secondaries.
    EXPECT_GT(with_hazards, 10u);
    EXPECT_GT(with_secondaries, 40u);
}

}  // namespace
