// SPDX-License-Identifier: Apache-2.0
// Issue 19's table for GPU-written inputs: capture cost, hazards found and false reports of
// examples/cluster_scene --compute-infos (a compute shader writes the cluster builds' src infos
// and count through buffer device addresses), with and without its barrier dispatch-to-sizes,
// per capture mode (CLASTRACE_DEVICE_ADDRESS_WRITES off / cheap / exact).
//
// Each round runs every configuration once, in turn (interleaved), on the test driver (lavapipe)
// with the capture layer serving the extension; times are the application's wall time and CPU
// time (user + system, all its threads) under the layer, median of the rounds. "serve only" is
// the layer with CLASTRACE_CAPTURE=0: the cost of serving alone. Each captured trace of the
// first round is replayed here.
// A reported hazard is *true* when its earlier side is a dispatch and its byte overlap meets a
// range the application says a dispatch wrote (its --json `computeWrites`); every other report
// is false. The real hazards the missing barrier makes are known from the sample's design: the
// two builds that read what the dispatch wrote (build:cluster-sizes and build:clusters) each
// read srcInfosArray and srcInfosCount, and build:move reads the same cluster count as its
// srcInfosCount, so 5 (build, field) pairs; "real hazards found" counts the distinct pairs the
// true reports name.
//
//   address_writes_bench [rounds=7] [max-clusters=0]
#include <clastrace/replay/hazard_report.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <sys/resource.h>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;

namespace {

constexpr uint32_t kRealHazards = 5;  // (build, field) pairs without the barrier: see above

struct Config {
    bool barrier = true;
    std::string mode;  // "serve only", "off", "cheap", "exact"
    bool capture() const { return mode != "serve only"; }
};

struct AppRun {
    double wall_ms = 0, cpu_ms = 0;
    nlohmann::json app;  // cluster_scene --json
    // The layer's report at exit (CLASTRACE_STATS): pauses and their median host time.
    unsigned long long pauses = 0;
    double pause_median_ms = 0;
};

std::string read_text(const fs::path& path) {
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

double children_cpu_ms() {
    rusage usage{};
    getrusage(RUSAGE_CHILDREN, &usage);
    auto ms = [](const timeval& t) { return double(t.tv_sec) * 1e3 + double(t.tv_usec) / 1e3; };
    return ms(usage.ru_utime) + ms(usage.ru_stime);
}

AppRun run_app(const Config& config, const std::string& max_clusters, const fs::path& trace,
               const fs::path& dir) {
    std::string line =
        "env -u CLASTRACE_OUTPUT -u CLASTRACE_CAPTURE -u CLASTRACE_DEBUG_JSON -u "
        "CLASTRACE_DEVICE_ADDRESS_WRITES -u VK_ICD_FILENAMES";
    line += clastrace::testsupport::test_driver().environment_words() +
            " VK_ADD_LAYER_PATH=" CLASTRACE_LAYER_MANIFEST_DIR
            " VK_INSTANCE_LAYERS=VK_LAYER_CLASTRACE_capture CLASTRACE_STATS=1";
    if (config.capture())
        line += " CLASTRACE_DEVICE_ADDRESS_WRITES=" + config.mode +
                " CLASTRACE_OUTPUT=" + trace.string();
    else
        line += " CLASTRACE_CAPTURE=0";
    const fs::path out = dir / "out.json", err = dir / "err.txt";
    line += std::string(" ") + CLUSTER_SCENE_APP + " --compute-infos --json --max-clusters " +
            max_clusters + (config.barrier ? "" : " --skip-barrier dispatch-to-sizes") + " >" +
            out.string() + " 2>" + err.string();
    AppRun run;
    const double cpu_before = children_cpu_ms();
    const auto started = std::chrono::steady_clock::now();
    const int status = std::system(line.c_str());
    run.wall_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started)
            .count();
    run.cpu_ms = children_cpu_ms() - cpu_before;
    if (status != 0) {
        std::fprintf(stderr, "address_writes_bench: cluster_scene failed:\n%s\n",
                     read_text(err).c_str());
        std::exit(1);
    }
    run.app = nlohmann::json::parse(read_text(out));
    const std::string report = read_text(err);
    if (const size_t at = report.find("clastrace: pauses: "); at != std::string::npos)
        std::sscanf(report.c_str() + at,
                    "clastrace: pauses: %llu handled; host time per pause: median %lf", &run.pauses,
                    &run.pause_median_ms);
    return run;
}

struct Judged {
    uint64_t certain = 0, possible = 0, true_reports = 0, false_reports = 0;
    std::set<std::pair<uint32_t, std::string>> found;  // (build's command index, field)
};

Judged judge(const clastrace::replay::ReplayReport& report, const nlohmann::json& app) {
    std::vector<std::pair<uint64_t, uint64_t>> written;
    for (const auto& w : app["scenes"][0]["computeWrites"])
        written.emplace_back(w[0].get<uint64_t>(), w[0].get<uint64_t>() + w[1].get<uint64_t>());
    Judged j;
    for (const clastrace::replay::HazardReport& h : report.hazards) {
        (h.possible() ? j.possible : j.certain) += 1;
        const bool meets = std::any_of(written.begin(), written.end(), [&](const auto& w) {
            return h.overlap.begin < w.second && w.first < h.overlap.end;
        });
        if (std::string(h.prior.command.name) == "vkCmdDispatch" && meets) {
            ++j.true_reports;
            j.found.insert(
                {h.later.command.command, h.later.field.substr(0, h.later.field.find('['))});
        } else {
            ++j.false_reports;
        }
    }
    return j;
}

clastrace::replay::ReplayReport replay(const fs::path& trace) {
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    if (!reader) {
        std::fprintf(stderr, "address_writes_bench: %s\n", error.message.c_str());
        std::exit(1);
    }
    return clastrace::replay::replay_trace(*reader, trace.string());
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
    const int rounds = argc > 1 ? std::max(1, std::atoi(argv[1])) : 7;
    const std::string max_clusters = argc > 2 ? argv[2] : "0";
    std::vector<Config> configs;
    for (bool barrier : {true, false})
        for (const char* mode : {"serve only", "off", "cheap", "exact"})
            configs.push_back({barrier, mode});
    const fs::path dir =
        fs::temp_directory_path() / ("address_writes_bench." + std::to_string(getpid()));
    fs::create_directories(dir);
    std::vector<std::vector<double>> wall(configs.size()), cpu(configs.size());
    std::vector<Judged> judged(configs.size());
    std::vector<uint64_t> trace_bytes(configs.size());
    std::vector<AppRun> first(configs.size());  // each configuration's first run
    for (int round = 0; round < rounds; ++round)
        for (size_t i = 0; i < configs.size(); ++i) {
            const fs::path trace = dir / (std::to_string(i) + ".clt");
            const AppRun run = run_app(configs[i], max_clusters, trace, dir);
            wall[i].push_back(run.wall_ms);
            cpu[i].push_back(run.cpu_ms);
            if (round == 0) first[i] = run;
            if (round == 0 && configs[i].capture()) {
                trace_bytes[i] = fs::file_size(trace);
                judged[i] = judge(replay(trace), run.app);
            }
        }
    fs::remove_all(dir);
    std::printf(
        "examples/cluster_scene --compute-infos --max-clusters %s, %s, median of %d "
        "interleaved rounds\n",
        max_clusters.c_str(), clastrace::testsupport::test_driver().driver_files.c_str(), rounds);
    std::printf(
        "| barrier dispatch-to-sizes | mode | app ms under the layer | app CPU ms | trace "
        "bytes | pauses (median host ms) | certain | possible | true reports | false reports "
        "| real hazards found |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n");
    for (size_t i = 0; i < configs.size(); ++i) {
        std::printf("| %s | %s | %.1f | %.1f |", configs[i].barrier ? "with" : "without",
                    configs[i].mode.c_str(), median(wall[i]), median(cpu[i]));
        if (!configs[i].capture()) {
            std::printf(" - | %llu (%.3f) | - | - | - | - | - |\n", first[i].pauses,
                        first[i].pause_median_ms);
            continue;
        }
        const Judged& j = judged[i];
        std::printf(" %llu | %llu (%.3f) | %llu | %llu | %llu | %llu | %zu of %u |\n",
                    (unsigned long long)trace_bytes[i], first[i].pauses, first[i].pause_median_ms,
                    (unsigned long long)j.certain, (unsigned long long)j.possible,
                    (unsigned long long)j.true_reports, (unsigned long long)j.false_reports,
                    j.found.size(), configs[i].barrier ? 0u : kRealHazards);
    }
    return 0;
}
