// SPDX-License-Identifier: Apache-2.0
// What traceable cluster BLASes cost a frame loop (issue 21): examples/rt_frame_loop
// --cluster-blas (per frame a CLAS build and a cluster BLAS build of 2 BLASes, a TLAS, one ray
// query per pixel) under VK_LAYER_CLASTRACE_capture, serving only (CLASTRACE_CAPTURE=0), with
// CLASTRACE_TRACEABLE_CLUSTERS=1 (the driver's BLAS built at each destination in the pause) and
// =0 (engine-only serving: the driver's rays miss every cluster BLAS). The two modes run in turn,
// `rounds` times (the first of a round alternates), and the table gives medians:
//   - the loop's time per frame (rt_frame_loop's loop_ms / frames) and the ratio to engine-only;
//   - the host time per pause (the layer's report);
//   - the driver's BLAS builds inside the pause per BLAS (the layer's CLASTRACE_STATS phase
//     "driver BLAS builds (traceable)": wall and CPU over 2 BLASes a frame).
//
//   traceable_frame_bench [frames=60] [rounds=7]
#include <clastrace/testsupport/test_driver.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

constexpr double kBlasesPerFrame = 2;  // rt_frame_loop's meshes

std::string read_text(const fs::path& path) {
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

struct Run {
    double loop_ms = 0, pause_median_ms = 0;
    double driver_wall_ms = 0, driver_cpu_ms = 0;  // the phase's totals (0 when engine-only)
};

// The numbers of one run from its stdout and stderr; false when the loop time is missing.
bool parse_run(const std::string& out, const std::string& err, Run& run) {
    const size_t loop = out.find("loop_ms=");
    if (loop == std::string::npos) return false;
    run.loop_ms = std::atof(out.c_str() + loop + 8);
    const size_t pauses = err.find("host time per pause: median ");
    if (pauses != std::string::npos) run.pause_median_ms = std::atof(err.c_str() + pauses + 28);
    const std::string phase = "driver BLAS builds (traceable) | ";
    const size_t driver = err.find(phase);
    if (driver != std::string::npos) {
        unsigned long long count = 0;
        std::sscanf(err.c_str() + driver + phase.size(), "%llu | %lf | %lf", &count,
                    &run.driver_wall_ms, &run.driver_cpu_ms);
    }
    return true;
}

Run run_loop(const fs::path& dir, uint32_t frames, bool traceable) {
    const fs::path out = dir / "out.txt", err = dir / "err.txt";
    std::string line = "env -u CLASTRACE_OUTPUT -u CLASTRACE_DEBUG_JSON -u VK_ICD_FILENAMES" +
                       clastrace::testsupport::test_driver().environment_words() +
                       " VK_ADD_LAYER_PATH=" CLASTRACE_LAYER_MANIFEST_DIR
                       " VK_INSTANCE_LAYERS=VK_LAYER_CLASTRACE_capture CLASTRACE_CAPTURE=0"
                       " CLASTRACE_STATS=1 CLASTRACE_TRACEABLE_CLUSTERS=" +
                       std::string(traceable ? "1" : "0") +
                       " " RT_FRAME_LOOP_APP " --cluster-blas --frames " + std::to_string(frames) +
                       " >" + out.string() + " 2>" + err.string();
    Run run;
    if (std::system(line.c_str()) != 0 || !parse_run(read_text(out), read_text(err), run)) {
        std::fprintf(stderr, "traceable_frame_bench: the frame loop failed:\n%s\n",
                     read_text(err).c_str());
        std::exit(1);
    }
    return run;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
    const uint32_t frames = argc > 1 ? uint32_t(std::atoi(argv[1])) : 60;
    const uint32_t rounds = argc > 2 ? uint32_t(std::atoi(argv[2])) : 7;
    if (frames == 0 || rounds == 0) {
        std::fprintf(stderr, "usage: traceable_frame_bench [frames=60] [rounds=7]\n");
        return 2;
    }
    const fs::path dir = fs::temp_directory_path() / "clastrace_traceable_frame_bench";
    fs::create_directories(dir);
    std::vector<double> frame_ms[2], pause_ms[2], blas_wall_ms, blas_cpu_ms;
    for (uint32_t r = 0; r < rounds; ++r)
        for (int k = 0; k < 2; ++k) {
            const bool traceable = (k + r) % 2 == 0;
            const Run run = run_loop(dir, frames, traceable);
            frame_ms[traceable].push_back(run.loop_ms / frames);
            pause_ms[traceable].push_back(run.pause_median_ms);
            if (!traceable) continue;
            blas_wall_ms.push_back(run.driver_wall_ms / (frames * kBlasesPerFrame));
            blas_cpu_ms.push_back(run.driver_cpu_ms / (frames * kBlasesPerFrame));
        }
    const double engine_only = median(frame_ms[0]);
    std::printf(
        "rt_frame_loop --cluster-blas, %u frames (%g BLASes a frame), medians of %u "
        "interleaved runs, serving only\n\n",
        frames, kBlasesPerFrame, rounds);
    std::printf(
        "| serving | frame ms | ratio | pause ms (median) | driver BLAS build per BLAS, "
        "wall ms | CPU ms |\n|---|---:|---:|---:|---:|---:|\n");
    std::printf("| engine only (CLASTRACE_TRACEABLE_CLUSTERS=0) | %.3f | 1.00x | %.3f | - | - |\n",
                engine_only, median(pause_ms[0]));
    std::printf(
        "| traceable (CLASTRACE_TRACEABLE_CLUSTERS=1) | %.3f | %.2fx | %.3f | %.3f | "
        "%.3f |\n",
        median(frame_ms[1]), median(frame_ms[1]) / engine_only, median(pause_ms[1]),
        median(blas_wall_ms), median(blas_cpu_ms));
    fs::remove_all(dir);
    return 0;
}
