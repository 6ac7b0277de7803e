// SPDX-License-Identifier: Apache-2.0
// Streaming analysis of 10^3..10^6 ops: throughput and peak resident memory (VmHWM), against
// the named peer "store-then-analyze": a two-pass analyzer that first keeps every object and
// region event in memory (what it must hold at the least) and then computes the same totals
// and median. Each measurement runs in a fresh process (this program re-executed), so one
// run's high-water mark does not leak into the next.
//
//   analyze_stream_bench                 the table
//   analyze_stream_bench --one MODE OPS OPS_PER_COMMAND
//                                      one measurement (MODE: stream | peer), for the tables
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "clastrace/analyze/analyzer.h"
#include "clastrace/analyze/render.h"
#include "fresh_process.h"
#include "synthetic_input.h"

using namespace clastrace::analyze;

namespace {

constexpr uint64_t kOpsPerCommand = 250;
constexpr uint64_t kCommandsPerSubmission = 4;  // largest submission: 1000 ops

using clastrace::bench::status_kib;

// The peer: keep everything, analyze at the end.
struct Stored {
    std::vector<CommandInfo> commands;
    std::vector<RegionInfo> regions;
    std::vector<ObjectInfo> objects;
};

void feed_store(Stored& s, const synthetic::StreamShape& shape) {
    // The events synthetic::feed_stream produces, recorded instead of folded.
    uint64_t next_region = 1;
    for (uint64_t c = 0; c < shape.commands; ++c) {
        CommandInfo ci;
        ci.ordinal = c;
        ci.submission = c / shape.commands_per_submission;
        ci.name = "vkCmdBuildClusterAccelerationStructureIndirectNV";
        ci.op_type = OpType::kBuildTriangleCluster;
        ci.op_count = shape.ops_per_command;
        ci.triangles = shape.ops_per_command * 64;
        ci.replay_ns = 1000 + (c * 7919) % 5000;
        s.commands.push_back(ci);
        const uint64_t slot = c % shape.commands_per_submission;
        const uint64_t implicit_base = 0x100000000ull + slot * 0x10000000ull;
        s.regions.push_back(RegionInfo{next_region++, "implicit", implicit_base,
                                       shape.ops_per_command * 2048, RegionRole::kImplicitData,
                                       true});
        s.regions.push_back(RegionInfo{next_region++, "scratch",
                                       0x900000000ull + slot * 0x1000000ull, 1 << 20,
                                       RegionRole::kScratch, true});
        uint64_t offset = 0;
        for (uint64_t op = 0; op < shape.ops_per_command; ++op) {
            ObjectInfo o;
            o.op_index = static_cast<uint32_t>(op);
            o.address = implicit_base + offset;
            o.engine_bytes = 1024 + 32 * ((c + op) % 32);
            o.triangles = 64;
            o.truncate_bits = static_cast<uint32_t>(op % 3) * 4;
            if (shape.with_object_regions)
                s.regions.push_back(RegionInfo{next_region++, "clas", o.address, o.engine_bytes,
                                               RegionRole::kObjectClas, true});
            s.objects.push_back(o);
            offset += o.engine_bytes;
        }
    }
}

int run_one(const std::string& mode, uint64_t ops, uint64_t ops_per_command) {
    synthetic::StreamShape shape;
    shape.ops_per_command = ops_per_command;
    shape.commands = std::max<uint64_t>(1, ops / ops_per_command);
    shape.commands_per_submission = kCommandsPerSubmission;
    shape.with_object_regions = true;
    const uint64_t rss_before = status_kib("VmRSS:");
    const auto t0 = std::chrono::steady_clock::now();
    uint64_t checksum = 0;
    if (mode == "stream") {
        Analyzer a("bench");
        synthetic::feed_stream(a, shape);
        AnalysisReport r = a.finish();
        checksum = r.sizes(OpType::kBuildTriangleCluster).engine_bytes.median() + r.overlap_events;
    } else {
        Stored s;
        feed_store(s, shape);
        std::vector<uint64_t> bytes;
        bytes.reserve(s.objects.size());
        for (const ObjectInfo& o : s.objects) bytes.push_back(o.engine_bytes);
        auto mid = bytes.begin() + static_cast<std::ptrdiff_t>((bytes.size() + 1) / 2 - 1);
        std::nth_element(bytes.begin(), mid, bytes.end());
        checksum = *mid + s.regions.size();
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%llu %.6f %llu %llu %llu\n",
                static_cast<unsigned long long>(shape.commands * ops_per_command), seconds,
                static_cast<unsigned long long>(status_kib("VmHWM:")),
                static_cast<unsigned long long>(rss_before),
                static_cast<unsigned long long>(checksum));
    return 0;
}

struct Measurement {
    uint64_t ops = 0, hwm_kib = 0, start_kib = 0;
    double seconds = 0;
    bool ok = false;
};

Measurement measure(const char* self, const char* mode, uint64_t ops,
                    uint64_t ops_per_command = kOpsPerCommand) {
    Measurement m;
    const auto out = clastrace::bench::run_fresh_process(self, {mode, std::to_string(ops),
                                                                std::to_string(ops_per_command)});
    unsigned long long o = 0, hwm = 0, start = 0, sum = 0;
    if (out && std::sscanf(out->c_str(), "%llu %lf %llu %llu %llu", &o, &m.seconds, &hwm, &start,
                           &sum) == 5) {
        m.ops = o;
        m.hwm_kib = hwm;
        m.start_kib = start;
        m.ok = true;
    }
    return m;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc == 5 && std::string(argv[1]) == "--one")
        return run_one(argv[2], std::stoull(argv[3]), std::stoull(argv[4]));
    std::printf(
        "clastrace analyze: streaming analysis, %llu ops per command, %llu commands per "
        "submission\n",
        static_cast<unsigned long long>(kOpsPerCommand),
        static_cast<unsigned long long>(kCommandsPerSubmission));
    std::printf("(largest submission %llu ops; every op has an object and an object region)\n",
                static_cast<unsigned long long>(kOpsPerCommand * kCommandsPerSubmission));
    std::printf("peer: store-then-analyze (keeps every event, then computes the median)\n\n");
    std::printf("%9s  %12s  %14s  %14s  %15s  %15s  %10s\n", "ops", "stream ops/s",
                "stream peak MiB", "stream growth", "peer peak MiB", "peer growth", "peak ratio");
    for (uint64_t ops : {1000ull, 10000ull, 100000ull, 1000000ull}) {
        Measurement s = measure(argv[0], "stream", ops);
        Measurement p = measure(argv[0], "peer", ops);
        if (!s.ok || !p.ok) {
            std::printf("%9llu  measurement failed\n", static_cast<unsigned long long>(ops));
            return 1;
        }
        auto mib = [](uint64_t kib) { return static_cast<double>(kib) / 1024.0; };
        std::printf("%9llu  %12.0f  %15.1f  %14.1f  %15.1f  %15.1f  %10.3f\n",
                    static_cast<unsigned long long>(s.ops), static_cast<double>(s.ops) / s.seconds,
                    mib(s.hwm_kib), mib(s.hwm_kib - s.start_kib), mib(p.hwm_kib),
                    mib(p.hwm_kib - p.start_kib),
                    static_cast<double>(s.hwm_kib) / static_cast<double>(p.hwm_kib));
    }

    std::printf(
        "\n10^6 ops, %llu commands per submission: peak memory follows the largest submission\n\n",
        static_cast<unsigned long long>(kCommandsPerSubmission));
    std::printf("%16s  %12s  %15s  %14s  %15s  %10s\n", "submission ops", "stream ops/s",
                "stream peak MiB", "stream growth", "peer peak MiB", "peak ratio");
    for (uint64_t per_command : {25ull, 250ull, 2500ull, 25000ull}) {
        Measurement s = measure(argv[0], "stream", 1000000, per_command);
        Measurement p = measure(argv[0], "peer", 1000000, per_command);
        if (!s.ok || !p.ok) {
            std::printf("%16llu  measurement failed\n",
                        static_cast<unsigned long long>(per_command * kCommandsPerSubmission));
            return 1;
        }
        auto mib = [](uint64_t kib) { return static_cast<double>(kib) / 1024.0; };
        std::printf("%16llu  %12.0f  %15.1f  %14.1f  %15.1f  %10.3f\n",
                    static_cast<unsigned long long>(per_command * kCommandsPerSubmission),
                    static_cast<double>(s.ops) / s.seconds, mib(s.hwm_kib),
                    mib(s.hwm_kib - s.start_kib), mib(p.hwm_kib),
                    static_cast<double>(s.hwm_kib) / static_cast<double>(p.hwm_kib));
    }
    return 0;
}
