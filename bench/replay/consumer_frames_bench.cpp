// SPDX-License-Identifier: Apache-2.0
// replay_consumer_bench [--frames N] [--small-frames M] [--runs R] [--triangles T] [--dir D]
// [--threads T] | --child-replay PATH on|off [--threads T] | --write-trace PATH FRAMES
//
// Replay of a ray-traced frame loop (rt_frame_bench_trace.h: per frame a vertex copy, BLAS
// builds into a 2-slot pool, a TLAS build, a ray-query dispatch or vkCmdTraceRaysKHR reading
// it, fences, a FrameBoundary) with the consumer model on and off
// (ReplayOptions::check_consumers; off still replays every build and checks every other
// access). Goal (issue 20): consumers add at most 1.2x; memory stays bounded by the largest
// frame, so M (default 100) and N (default 1000) frames peak at the same memory.
//
// Each run is a fresh child process, so its peak RSS (VmHWM) is that run's alone; runs of the
// two modes interleave (on/off, then off/on) and each cell is the median of R (>= 7) runs.
#include "rt_frame_bench_trace.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

using namespace clastrace;

namespace {

double wall_now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

// CPU seconds of the whole process (all threads): steadier than wall time on a busy machine.
double cpu_now() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// A /proc/self/status line's kB (VmHWM: this process image's peak; VmRSS: now). Not
// getrusage's ru_maxrss, which a child keeps from its parent across fork and exec.
uint64_t status_kb(const char* key) {
    FILE* f = std::fopen("/proc/self/status", "r");
    if (!f) return 0;
    char line[256];
    unsigned long long kb = 0;
    const std::string format = std::string(key) + ": %llu kB";
    while (std::fgets(line, sizeof line, f))
        if (std::sscanf(line, format.c_str(), &kb) == 1) break;
    std::fclose(f);
    return kb;
}

// What one child run reports back.
struct RunResult {
    double wall = 0, cpu = 0;
    uint64_t peak_kb = 0, start_kb = 0, image_peak = 0, accesses = 0, khr_builds = 0;
    uint64_t raw_bytes = 0;  // the trace's decompressed chunk bytes
    uint64_t problems = 0;   // findings + hazards + damage: a clean trace has none
    bool ok = false;
};

int child_replay(const std::string& path, bool consumers) {
    const uint64_t start_kb = status_kb("VmRSS");
    const double w0 = wall_now(), c0 = cpu_now();
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    if (!reader) {
        std::fprintf(stderr, "cannot open %s: %s\n", path.c_str(), error.message.c_str());
        return 2;
    }
    replay::ReplayOptions options;
    options.check_consumers = consumers;
    const replay::ReplayReport r = replay::replay_trace(*reader, path, options);
    const double wall = wall_now() - w0, cpu = cpu_now() - c0;
    const uint64_t problems = r.findings.size() + r.hazards.size() + r.trace_damage.size();
    if (!r.findings.empty())
        std::fprintf(stderr, "first finding: %s\n", r.findings[0].format().c_str());
    if (!r.hazards.empty())
        std::fprintf(stderr, "first hazard: %s\n", r.hazards[0].format().c_str());
    std::printf("RESULT %.6f %.6f %llu %llu %llu %llu %llu %llu %llu\n", wall, cpu,
                (unsigned long long)status_kb("VmHWM"), (unsigned long long)start_kb,
                (unsigned long long)r.counts.peak_image_bytes,
                (unsigned long long)r.counts.accesses, (unsigned long long)r.counts.khr_builds,
                (unsigned long long)problems, (unsigned long long)reader->stats().raw_bytes);
    return 0;
}

RunResult run_child(const std::string& path, bool consumers, const std::string& threads) {
    RunResult r;
    int fds[2];
    if (pipe(fds) != 0) return r;
    const pid_t pid = fork();
    if (pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        close(fds[1]);
        const char* self = "/proc/self/exe";
        execl(self, self, "--child-replay", path.c_str(), consumers ? "on" : "off", "--threads",
              threads.c_str(), static_cast<char*>(nullptr));
        _exit(127);
    }
    close(fds[1]);
    std::string out;
    char buf[512];
    ssize_t n;
    while ((n = read(fds[0], buf, sizeof buf)) > 0) out.append(buf, size_t(n));
    close(fds[0]);
    int status = 0;
    waitpid(pid, &status, 0);
    const size_t at = out.find("RESULT ");
    unsigned long long v[7] = {};
    if (at != std::string::npos &&
        std::sscanf(out.c_str() + at, "RESULT %lf %lf %llu %llu %llu %llu %llu %llu %llu", &r.wall,
                    &r.cpu, &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &v[6]) == 9) {
        r.peak_kb = v[0];
        r.start_kb = v[1];
        r.image_peak = v[2];
        r.accesses = v[3];
        r.khr_builds = v[4];
        r.problems = v[5];
        r.raw_bytes = v[6];
        r.ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
    }
    return r;
}

template <class Field>
double median(const std::vector<RunResult>& runs, Field field) {
    std::vector<double> values;
    for (const RunResult& r : runs) values.push_back(double(field(r)));
    std::sort(values.begin(), values.end());
    const size_t n = values.size();
    return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

double mib(double bytes) { return bytes / (1024.0 * 1024.0); }

struct Options {
    uint32_t frames = 1000, small_frames = 100, runs = 7, triangles = 128;
    std::string dir = "/tmp", threads = "0";  // 0: TBB's default
};

// One trace size: R interleaved runs of each mode, then one table row per mode.
bool bench_size(const Options& o, uint32_t frames) {
    bench::RtFrameShape shape;
    shape.frames = frames;
    shape.triangles_per_mesh = o.triangles;
    const std::string path = o.dir + "/replay_consumer_bench_" + std::to_string(frames) + "_" +
                             std::to_string(getpid()) + ".clt";
    const bench::RtFrameStats stats = bench::write_rt_frame_trace(path, shape);
    std::vector<RunResult> on, off;
    for (uint32_t run = 0; run < o.runs; ++run) {
        const bool on_first = run % 2 == 0;
        for (int k = 0; k < 2; ++k) {
            const bool consumers = (k == 0) == on_first;
            const RunResult r = run_child(path, consumers, o.threads);
            if (!r.ok) {
                std::printf("| %u | %s | child replay failed |\n", frames,
                            consumers ? "on" : "off");
                std::remove(path.c_str());
                return false;
            }
            if (r.problems)
                std::fprintf(stderr, "warning: %u frames, consumers %s: %llu findings/hazards\n",
                             frames, consumers ? "on" : "off", (unsigned long long)r.problems);
            (consumers ? on : off).push_back(r);
        }
    }
    std::remove(path.c_str());
    const double off_wall = median(off, [](const RunResult& r) { return r.wall; });
    const double off_cpu = median(off, [](const RunResult& r) { return r.cpu; });
    for (const auto* runs : {&on, &off}) {
        const double wall = median(*runs, [](const RunResult& r) { return r.wall; });
        const double cpu = median(*runs, [](const RunResult& r) { return r.cpu; });
        const double peak = median(*runs, [](const RunResult& r) { return r.peak_kb; });
        const double over = median(*runs, [](const RunResult& r) {
            return r.peak_kb - std::min(r.peak_kb, r.start_kb);
        });
        const RunResult& last = runs->back();
        std::printf(
            "| %u | %s | %.2f | %.2f | %.3f | %.3f | %.2fx | %.2fx | %.1f | %.1f | %.2f | %.3f | "
            "%.3f | %.3f | %llu | %llu | %llu |\n",
            frames, runs == &on ? "on" : "off", mib(double(stats.file_bytes)),
            mib(double(last.raw_bytes)), wall, cpu, wall / off_wall, cpu / off_cpu, peak / 1024.0,
            over / 1024.0, mib(double(last.image_peak)),
            mib(double(stats.largest_frame_snapshot_bytes)),
            mib(double(last.raw_bytes) / double(frames)), mib(double(stats.working_set_bytes)),
            (unsigned long long)last.accesses, (unsigned long long)last.khr_builds,
            (unsigned long long)last.problems);
    }
    std::fflush(stdout);
    return true;
}

int usage(const char* self) {
    std::fprintf(stderr,
                 "usage: %s [--frames N] [--small-frames M] [--runs R (>= 7)] [--triangles T] "
                 "[--dir D] [--threads T]\n",
                 self);
    return 2;
}

}  // namespace

int main(int argc, char** argv) {
    Options o;
    std::unique_ptr<tbb::global_control> threads;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        const bool has_value = i + 1 < argc;
        if (a == "--child-replay" && i + 2 < argc) {
            // --threads after the mode caps the engine's TBB workers in the child.
            if (i + 4 < argc && std::string(argv[i + 3]) == "--threads" &&
                std::strtoul(argv[i + 4], nullptr, 10) > 0)
                threads = std::make_unique<tbb::global_control>(
                    tbb::global_control::max_allowed_parallelism,
                    std::strtoul(argv[i + 4], nullptr, 10));
            return child_replay(argv[i + 1], std::string(argv[i + 2]) == "on");
        }
        if (a == "--write-trace" && i + 2 < argc) {  // keep one trace, e.g. for a profiler
            bench::RtFrameShape shape;
            shape.frames = uint32_t(std::strtoul(argv[i + 2], nullptr, 10));
            const bench::RtFrameStats stats = bench::write_rt_frame_trace(argv[i + 1], shape);
            std::printf("%s: %llu frames, %llu submissions\n", argv[i + 1],
                        (unsigned long long)stats.frames, (unsigned long long)stats.submissions);
            return 0;
        }
        if (a == "--frames" && has_value)
            o.frames = uint32_t(std::strtoul(argv[++i], nullptr, 10));
        else if (a == "--small-frames" && has_value)
            o.small_frames = uint32_t(std::strtoul(argv[++i], nullptr, 10));
        else if (a == "--runs" && has_value)
            o.runs = uint32_t(std::strtoul(argv[++i], nullptr, 10));
        else if (a == "--triangles" && has_value)
            o.triangles = uint32_t(std::strtoul(argv[++i], nullptr, 10));
        else if (a == "--dir" && has_value)
            o.dir = argv[++i];
        else if (a == "--threads" && has_value)
            o.threads = argv[++i];
        else
            return usage(argv[0]);
    }
    if (o.runs == 0 || o.frames == 0) return usage(argv[0]);
    std::printf(
        "replay of a ray-traced frame loop, consumer model on and off (ReplayOptions::"
        "check_consumers); %u meshes x %u triangles per frame, 2 frames in flight, 2 pool slots; "
        "median of %u interleaved runs, each in a fresh process; engine threads: %s\n",
        bench::RtFrameShape{}.meshes, o.triangles, o.runs,
        o.threads == "0" ? "TBB default" : o.threads.c_str());
    std::printf(
        "| frames | consumers | trace MiB | decompressed MiB | wall s | CPU s | wall vs off | CPU "
        "vs off | peak RSS "
        "MiB | RSS over start MiB | image peak MiB | largest frame's snapshots MiB | decompressed "
        "MiB "
        "per frame | working set MiB | accesses | KHR builds | findings+hazards |\n");
    std::printf(
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    bool ok = true;
    if (o.small_frames > 0 && o.small_frames != o.frames) ok &= bench_size(o, o.small_frames);
    ok &= bench_size(o, o.frames);
    return ok ? 0 : 1;
}
