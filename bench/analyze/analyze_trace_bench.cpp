// SPDX-License-Identifier: Apache-2.0
// `clastrace analyze` on a real trace file: the bench writes a trace of N CLAS-build ops with
// the TraceWriter (clusters of 1..8 triangles, implicit destinations rebuilt in place every
// command, a barrier and a GPU timestamp pair around each command, captured dstSizesArray),
// then measures in fresh processes (this program re-executed, so high-water marks do not
// leak between runs):
//   replay     replay_trace alone (what any analysis pays: engine, memory image, sync model)
//   stream     analyze_trace: the feeder holds one submission at a time
//   peer       "store-then-analyze": the same feeder holding every submission until the end
//              of the trace (what an analysis over a finished replay has to keep), same report
// and prints peak resident memory (VmHWM), time, and the largest submission.
//
//   analyze_trace_bench                       the tables (10^4..10^6 ops; then 10^6 ops with
//                                             growing submissions)
//   analyze_trace_bench --one MODE TRACE REBUILDS   one measurement (REBUILDS: untruncated rebuilds per command)
//   analyze_trace_bench --knob                the untruncated-rebuilds table only
//   analyze_trace_bench --write TRACE OPS OPS_PER_COMMAND COMMANDS_PER_SUBMISSION
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/trace_building/cluster_records.h>
#include <clastrace/trace_building/cluster_structs.h>
#include <clastrace/trace_building/command_records.h>
#include <clastrace/trace_building/engine_mirror.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/trace_building/trace_header.h>
#include <clastrace/traces/trace_reader.h>

#include "fresh_process.h"

#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

using namespace clastrace;

namespace {

namespace tb = trace_building;

constexpr uint64_t kVertices = 0x10000000, kIndices = 0x10010000, kInfos = 0x20000000,
                   kArrays = 0x30000000, kScratch = 0x38000000, kPool = 0x40000000;

using bench::status_kib;

// Writes the trace; returns its size in bytes.
uint64_t write_trace(const std::string& path, uint64_t ops, uint64_t per_command,
                     uint64_t per_submission, uint32_t truncate_bits = 0) {
    fbs::TraceHeaderT h = tb::trace_header("bench driver", "NVIDIA", "analyze_trace_bench");
    h.device->timestamp_period_ns = 1.0f;
    tb::RecordWriter w(path, h);

    // One command's inputs: cluster i is a strip of 1 + i % 8 triangles.
    const auto n = static_cast<uint32_t>(per_command);
    std::vector<float> vertices;
    for (uint32_t i = 0; i < 10; ++i)
        for (float v : {1.37f * float(i) + 0.1f, float(i % 2) * 1.9f, 0.3f * float(i * i % 7)})
            vertices.push_back(v);
    std::vector<uint32_t> indices;
    for (uint32_t i = 0; i < 8; ++i)
        for (uint32_t k : {i, i + 1, i + 2}) indices.push_back(k);
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> infos(n);
    for (uint32_t i = 0; i < n; ++i) {
        infos[i] = tb::triangle_cluster_info(i, 1 + i % 8, 3 + i % 8, kIndices, 4, kVertices);
        infos[i].positionTruncateBitCount = truncate_bits;
    }
    const uint64_t pool = per_command * 1024, scratch = per_command * 16;
    const uint64_t usage = VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT |
                           VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR |
                           VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    tb::EngineMirror mirror;
    uint64_t handle = 0x100;
    for (auto [address, size] : {std::pair<uint64_t, uint64_t>{kVertices, 4096},
                                 {kIndices, 4096},
                                 {kInfos, n * sizeof infos[0]},
                                 {kArrays, n * 16ull},
                                 {kScratch, scratch},
                                 {kPool, pool}}) {
        w.buffer(++handle, address, size, usage, 1, address);
        mirror.add_buffer(address, size, usage);
    }
    const auto tri = tb::triangle_cluster_limits(8, 10, n * 8, n * 10);
    auto info = tb::cluster_commands(tb::cluster_op_input(n, &tri));
    info.dstImplicitData = kPool;
    info.scratchData = kScratch;
    info.dstAddressesArray = {kArrays, 8, n * 8ull};
    info.dstSizesArray = {kArrays + n * 8ull, 4, n * 4ull};
    info.srcInfosArray = {kInfos, sizeof infos[0], n * sizeof infos[0]};
    mirror.write(kInfos, tb::bytes_of(infos));
    mirror.write(kVertices, tb::bytes_of(vertices));
    mirror.write(kIndices, tb::bytes_of(indices));
    const engine::ExecutionRecord r = mirror.execute(info);
    std::vector<uint64_t> addresses(n);
    std::vector<uint32_t> sizes(n);
    for (uint32_t i = 0; i < n; ++i) {
        addresses[i] = r.ops[i].dst_address;
        sizes[i] = static_cast<uint32_t>(r.ops[i].dst_size);
    }
    fbs::GetClusterBuildSizesT q;
    q.input = tb::cluster_input(info.input);
    q.acceleration_structure_size = pool;
    q.build_scratch_size = scratch;
    w.append(std::move(q));

    const uint64_t commands = std::max<uint64_t>(1, ops / per_command);
    uint64_t cb = 0xc000, ticks = 1000;
    for (uint64_t c = 0; c < commands; ++c) {
        if (c % per_submission == 0)
            w.append(tb::command_buffer_begin(++cb, VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT));
        const uint64_t as = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                            VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
        w.append(tb::memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                    as, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                                    as));
        fbs::GpuTimestampT ts;
        ts.command_buffer = cb;
        ts.ticks = ticks;
        ts.ticks_valid = true;
        w.append(ts);
        fbs::CmdBuildClusterAccelerationStructureIndirectT b = tb::cluster_build(cb, info);
        b.inputs = {w.snapshot(kInfos, tb::bytes_of(infos)),
                    w.snapshot(kVertices, tb::bytes_of(vertices)),
                    w.snapshot(kIndices, tb::bytes_of(indices))};
        b.outputs = {w.snapshot(kArrays, tb::bytes_of(addresses)),
                     w.snapshot(kArrays + n * 8ull, tb::bytes_of(sizes))};
        w.append(std::move(b));
        ticks += 20 * per_command;  // 20 ns per op on the "GPU"
        ts.ticks = ticks;
        w.append(ts);
        ticks += 500;
        if (c % per_submission == per_submission - 1 || c + 1 == commands) {
            w.end_and_submit(0x9001, cb, 0xfe1);
            w.wait_fence(0xfe1);
        }
    }
    w.finish();
    return std::filesystem::file_size(path);
}

// The peer: the feeder never sees a submission end, so it holds every event until finish().
class HoldEverything final : public replay::ReplayObserver {
public:
    explicit HoldEverything(analyze::ReplayStreamFeeder& f) : f_(f) {}
    void on_record(const traces::RecordView& v) override { f_.on_record(v); }
    void on_submission_begin(uint32_t s) override { f_.on_submission_begin(s); }
    void on_command(const replay::ReplayedCommand& c) override { f_.on_command(c); }
    void on_finding(const replay::ReplayFinding& f) override { f_.on_finding(f); }
    void on_hazard(const replay::HazardReport& h) override { f_.on_hazard(h); }

private:
    analyze::ReplayStreamFeeder& f_;
};

int run_one(const std::string& mode, const std::string& path, uint32_t rebuilds) {
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    if (!reader) {
        std::fprintf(stderr, "%s\n", e.message.c_str());
        return 2;
    }
    const uint64_t rss_before = status_kib("VmRSS:");
    const auto t0 = std::chrono::steady_clock::now();
    uint64_t ops = 0, objects = 0, bytes = 0, largest_ops = 0, largest_events = 0, held = 0,
             hazards = 0;
    uint64_t measured = 0, truncated_bytes = 0, untruncated_bytes = 0;
    if (mode == "replay") {
        const replay::ReplayReport r = replay::replay_trace(*reader, path);
        ops = r.counts.cluster_ops;
        hazards = r.hazards.size();
    } else if (mode == "stream") {
        analyze::AnalyzeOptions options;
        options.stream.untruncated_rebuilds_per_command = rebuilds;
        const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path, options);
        for (const analyze::TruncationRow& t : a.report.truncation) {
            measured += t.objects_with_untruncated;
            truncated_bytes += t.engine_bytes_of_those;
            untruncated_bytes += t.untruncated_bytes;
        }
        ops = a.report.ops;
        objects = a.report.objects;
        bytes = a.report.sizes(analyze::OpType::kBuildTriangleCluster).engine_bytes.sum();
        largest_ops = a.report.largest_submission_ops;
        largest_events = a.stream.largest_submission_events;
        held = a.stream.peak_held_bytes;
        hazards = a.report.hazards_total;
    } else {
        analyze::Analyzer analyzer(path);
        analyze::ReplayStreamFeeder feeder(analyzer, 1.0, true,
                                           [&](uint64_t hash, std::vector<uint8_t>* out) {
                                               return !reader->read_contents(hash, out);
                                           });
        HoldEverything hold(feeder);
        replay::ReplayOptions options;
        options.observer = &hold;
        const replay::ReplayReport r = replay::replay_trace(*reader, path, options);
        feeder.finish(reader->stats());
        const analyze::AnalysisReport report = analyzer.finish();
        ops = report.ops;
        objects = report.objects;
        bytes = report.sizes(analyze::OpType::kBuildTriangleCluster).engine_bytes.sum();
        largest_ops = report.largest_submission_ops;
        largest_events = feeder.stats().largest_submission_events;
        held = feeder.stats().peak_held_bytes;
        hazards = report.hazards_total;
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("%llu %.6f %llu %llu %llu %llu %llu %llu %llu %llu %llu %llu %llu\n",
                (unsigned long long)ops, seconds, (unsigned long long)status_kib("VmHWM:"),
                (unsigned long long)rss_before, (unsigned long long)objects,
                (unsigned long long)bytes, (unsigned long long)largest_ops,
                (unsigned long long)largest_events, (unsigned long long)held,
                (unsigned long long)hazards, (unsigned long long)measured,
                (unsigned long long)truncated_bytes, (unsigned long long)untruncated_bytes);
    return 0;
}

struct Measurement {
    unsigned long long ops = 0, hwm = 0, start = 0, objects = 0, bytes = 0, largest_ops = 0,
                       largest_events = 0, held = 0, hazards = 0, measured = 0, truncated = 0,
                       untruncated = 0;
    double seconds = 0;
    bool ok = false;
};

Measurement measure(const char* self, const char* mode, const std::string& trace,
                    uint32_t rebuilds = 8) {
    Measurement m;
    const auto out = bench::run_fresh_process(self, {mode, trace, std::to_string(rebuilds)});
    m.ok = out && std::sscanf(out->c_str(),
                              "%llu %lf %llu %llu %llu %llu %llu %llu %llu %llu %llu %llu %llu",
                              &m.ops, &m.seconds, &m.hwm, &m.start, &m.objects, &m.bytes,
                              &m.largest_ops, &m.largest_events, &m.held, &m.hazards, &m.measured,
                              &m.truncated, &m.untruncated) == 13;
    return m;
}

double mib(unsigned long long kib) { return static_cast<double>(kib) / 1024.0; }

bool row(const char* self, const std::string& dir, uint64_t ops, uint64_t per_command,
         uint64_t per_submission) {
    const std::string trace =
        dir + "/bench_" + std::to_string(ops) + "_" + std::to_string(per_command) + ".clt";
    const auto t0 = std::chrono::steady_clock::now();
    const uint64_t file = write_trace(trace, ops, per_command, per_submission);
    const double write_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const Measurement r = measure(self, "replay", trace), s = measure(self, "stream", trace),
                      p = measure(self, "peer", trace);
    std::filesystem::remove(trace);
    if (!r.ok || !s.ok || !p.ok || s.bytes != p.bytes || s.objects != p.objects) {
        std::printf("%9llu  measurement failed (or stream and peer disagree)\n",
                    (unsigned long long)ops);
        return false;
    }
    std::printf("%9llu %7llu %8.1f %9.1f %7.1f %9.1f %8.1f %9.1f %7.1f %7.3f %9llu %7.1f\n", s.ops,
                s.largest_ops, static_cast<double>(file) / 1024.0, mib(r.hwm), r.seconds,
                mib(s.hwm), s.seconds, mib(p.hwm), p.seconds,
                static_cast<double>(s.hwm) / static_cast<double>(p.hwm), s.largest_events,
                static_cast<double>(s.held) / (1024.0 * 1024.0));
    std::fflush(stdout);
    (void)write_s;
    return true;
}

void header() {
    std::printf("%9s %7s %8s %9s %7s %9s %8s %9s %7s %7s %9s %7s\n", "ops", "sub ops", "file",
                "replay", "replay", "stream", "stream", "peer", "peer", "stream/", "largest",
                "held");
    std::printf("%9s %7s %8s %9s %7s %9s %8s %9s %7s %7s %9s %7s\n", "", "(max)", "KiB", "peak MiB",
                "s", "peak MiB", "s", "peak MiB", "s", "peer", "sub evts", "MiB");
}

// The knob: truncated clusters rebuilt at positionTruncateBitCount 0 per command. Each
// rebuild is one more engine build; what it buys is a measured (not estimated) saving.
int knob_table(const char* self, const std::string& dir) {
    std::printf(
        "\nStreamOptions::untruncated_rebuilds_per_command, 3x10^5 ops at positionTruncateBitCount "
        "8\n"
        "(1000 ops per command; least time of 3 runs): analysis time vs how many objects' saving "
        "is measured\n");
    std::printf("%9s %9s %9s %10s %12s %14s %8s\n", "rebuilds", "stream s", "vs 0", "measured",
                "truncated B", "untruncated B", "saved");
    const std::string trace = dir + "/bench_knob.clt";
    write_trace(trace, 300000, 1000, 4, 8);
    double base = 0;
    for (uint32_t rebuilds : {0u, 8u, 64u, 1000u}) {
        Measurement m = measure(self, "stream", trace, rebuilds);
        for (int again = 0; again < 2 && m.ok;
             ++again) {  // the least of three runs: the machine is shared
            const Measurement n = measure(self, "stream", trace, rebuilds);
            if (n.ok && n.seconds < m.seconds) m = n;
        }
        if (!m.ok) {
            std::printf("%9u  measurement failed\n", rebuilds);
            return 1;
        }
        if (rebuilds == 0) base = m.seconds;
        std::printf("%9u %9.2f %9.2f %10llu %12llu %14llu %7.1f%%\n", rebuilds, m.seconds,
                    m.seconds / base, m.measured, m.truncated, m.untruncated,
                    m.untruncated ? 100.0 * (double(m.untruncated) - double(m.truncated)) /
                                        double(m.untruncated)
                                  : 0.0);
        std::fflush(stdout);
    }
    std::filesystem::remove(trace);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc == 5 && std::string(argv[1]) == "--one")
        return run_one(argv[2], argv[3], std::stoul(argv[4]));
    if (argc == 6 && std::string(argv[1]) == "--write") {
        std::printf("%llu bytes\n",
                    (unsigned long long)write_trace(argv[2], std::stoull(argv[3]),
                                                    std::stoull(argv[4]), std::stoull(argv[5])));
        return 0;
    }
    const std::string dir = std::filesystem::temp_directory_path().string();
    if (argc == 2 && std::string(argv[1]) == "--knob") return knob_table(argv[0], dir);
    std::printf(
        "clastrace analyze on generated trace files: CLAS builds of 1..8 triangles, implicit "
        "destinations,\n"
        "a barrier and two GPU timestamps per command, captured sizes. Peak = VmHWM of a fresh "
        "process.\n"
        "replay: replay alone; stream: analyze_trace (one submission held); peer: "
        "store-then-analyze\n"
        "(the same feeder holding every submission to the end; same report, checked).\n"
        "held MiB: the feeder's estimate of the events it held at its peak.\n\n");
    std::printf("1000 ops per command, 4 commands per submission\n");
    header();
    for (uint64_t ops : {10000ull, 100000ull, 1000000ull})
        if (!row(argv[0], dir, ops, 1000, 4)) return 1;
    std::printf(
        "\n10^6 ops, growing submissions (4 commands each): the stream's peak follows the largest "
        "submission\n");
    header();
    for (uint64_t per_command : {250ull, 2500ull, 25000ull})
        if (!row(argv[0], dir, 1000000, per_command, 4)) return 1;

    return knob_table(argv[0], dir);
}
