// SPDX-License-Identifier: Apache-2.0
// clastrace replay TRACE: re-executes the captured builds, moves and copies on the
// built-in engine in queue order; reports hazards, broken rules and output mismatches, and
// apart from them the notes on the replay's own limits (which leave the exit status 0).
#include "commands.h"
#include "json_output.h"
#include "reader_options.h"
#include "trace_error_json.h"
#include "whole_number_option.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <unistd.h>

namespace clastrace::tools {

namespace {

// Findings kept in memory at most (each holds its message text); more are counted.
constexpr uint64_t kMostFindingsKept = 1'000'000;

struct ReplayArgs {
    std::string trace;
    bool json = false;
    std::string ops;
    int64_t submit = -1;
    bool no_hazards = false;
    bool no_verify = false;
    bool progress = false;
    std::size_t max_findings = 1000;
    uint32_t threads = 0;   // 0: the machine's cores
    std::string traversal;  // "", "float32" or "double" (CLI11 checks the value)
    traces::TraceReaderOptions reader{.verify_content_keys = true};
};

// "N..M", "N.." or "N" (one command).
bool parse_ops(const std::string& text, uint64_t* first, uint64_t* last) {
    try {
        size_t dots = text.find("..");
        size_t used = 0;
        if (dots == std::string::npos) {
            *first = *last = std::stoull(text, &used);
            return used == text.size();
        }
        *first = std::stoull(text.substr(0, dots), &used);
        if (used != dots) return false;
        std::string rest = text.substr(dots + 2);
        if (rest.empty()) return true;
        *last = std::stoull(rest, &used);
        return used == rest.size() && *last >= *first;
    } catch (const std::exception&) {
        return false;
    }
}

int refuse(const ReplayArgs& args, const traces::TraceError& error) {
    if (args.json) {
        print_trace_error_json(args.trace, error);
    } else {
        std::fprintf(stderr, "clastrace replay: %s\n", error.message.c_str());
    }
    return kExitUsage;
}

// --submit K names a submission the trace does not hold: say how many it holds rather
// than replay nothing and call that clean.
traces::TraceError submission_not_in_trace(const ReplayArgs& args, uint64_t submissions,
                                           bool damaged) {
    const std::string holds = submissions == 0 ? "no submissions"
                              : submissions == 1
                                  ? "1 submission (--submit 0)"
                                  : std::to_string(submissions) + " submissions (--submit 0 to " +
                                        std::to_string(submissions - 1) + ")";
    traces::TraceError error;  // not at a file offset: no "offset 0" in the message
    error.code = traces::TraceErrorCode::kInvalidArgument;
    error.message = args.trace + ": --submit " + std::to_string(args.submit) + ": " +
                    (damaged ? "the readable part of the trace holds " + holds +
                                   "; the rest is damaged (clastrace info shows where)"
                             : "the trace holds " + holds);
    return error;
}

int run_replay(const ReplayArgs& args) {
    replay::ReplayOptions options;
    options.check_hazards = !args.no_hazards;
    options.verify_outputs = !args.no_verify;
    options.submission = args.submit;
    options.max_findings = args.max_findings;
    options.threads = args.threads;
    if (args.traversal == "double")
        options.ray_check_traversal = replay::RayCheckTraversal::kDouble;
    if (args.traversal == "float32")
        options.ray_check_traversal = replay::RayCheckTraversal::kFloat32;
    if (!args.ops.empty() && !parse_ops(args.ops, &options.first_command, &options.last_command)) {
        std::fprintf(
            stderr,
            "clastrace replay: --ops takes N..M, N.. or N (command sequence numbers), not '%s'\n",
            args.ops.c_str());
        return kExitUsage;
    }
    traces::TraceError error;
    std::unique_ptr<traces::TraceReader> reader =
        traces::TraceReader::open(args.trace, &error, args.reader);
    if (!reader) return refuse(args, error);
    // A finished trace's index says how many submissions it holds; an unfinished one is
    // counted by the replay itself (below).
    if (args.submit >= 0 && reader->has_index() &&
        uint64_t(args.submit) >= reader->indexed_submission_count()) {
        return refuse(args,
                      submission_not_in_trace(args, reader->indexed_submission_count(), false));
    }
    const bool show_progress = args.progress || isatty(STDERR_FILENO);
    if (show_progress) {
        // At most five lines a second: a terminal redraw per 64 records would cost more than the replay.
        options.progress = [last = std::chrono::steady_clock::time_point{}](
                               const replay::ReplayProgress& p) mutable {
            const auto now = std::chrono::steady_clock::now();
            if (now - last < std::chrono::milliseconds(200)) return;
            last = now;
            const double pct =
                p.file_size ? 100.0 * double(p.bytes_read) / double(p.file_size) : 0.0;
            std::fprintf(stderr, "\rreplay: %5.1f%%  %llu records, %llu commands", pct,
                         (unsigned long long)p.records, (unsigned long long)p.commands);
        };
    }
    replay::ReplayReport report = replay::replay_trace(*reader, args.trace, options);
    if (show_progress) std::fprintf(stderr, "\rreplay: done%40s\n", "");
    if (args.submit >= 0 && uint64_t(args.submit) >= report.counts.submissions) {
        return refuse(args, submission_not_in_trace(args, report.counts.submissions,
                                                    !report.trace_damage.empty()));
    }
    if (args.json) {
        std::cout << json_text(replay::to_json(report)) << "\n";
    } else {
        std::cout << replay::format_text(report);
    }
    return report.clean() ? kExitOk : kExitFindings;
}

}  // namespace

Command register_replay(CLI::App& app) {
    auto args = std::make_shared<ReplayArgs>();
    CLI::App* sub = app.add_subcommand(
        "replay",
        "Re-execute every captured cluster build/move on the built-in engine in queue order and "
        "report synchronization hazards, broken rules (VUIDs) and outputs that differ from the "
        "capture; what the replay itself cannot do (another driver's serialized object, its "
        "memory budget, commands not replayed) is listed apart as notes. "
        "Exit: 0 clean (notes allowed), 1 findings, hazards or damage, 2 usage error or "
        "unreadable trace.");
    sub->add_option("TRACE", args->trace, "the .clt trace")->required();
    sub->add_flag("--json", args->json,
                  "print one JSON object (docs/replay.md): findings, hazards and notes apart");
    sub->add_option("--ops", args->ops,
                    "replay only commands N..M (execution sequence numbers, as printed [#N])");
    sub->add_option("--submit", args->submit,
                    "replay only the commands of submission K (0 is the first)")
        ->check(whole_number_from(0, UINT32_MAX, "a submission number"));
    sub->add_flag("--no-hazards", args->no_hazards, "skip the synchronization model");
    sub->add_flag("--no-verify", args->no_verify,
                  "skip comparing captured outputs with the engine's");
    sub->add_flag("--progress", args->progress,
                  "progress on stderr even when it is not a terminal");
    sub->add_option("--max-findings", args->max_findings,
                    "findings, hazards and notes kept (each), 1 to " +
                        std::to_string(kMostFindingsKept) + " (the rest are counted)")
        ->check(whole_number_from(1, kMostFindingsKept, "the number of findings kept"))
        ->capture_default_str();
    sub->add_option("--traversal", args->traversal,
                    "arithmetic of the engine's traversal for the trace's ray checks: float32 "
                    "(the default: as the drivers that answered them trace) or double")
        ->check(CLI::IsMember({"float32", "double"}));
    sub->add_option("--threads", args->threads,
                    "threads the replay may use, 1 to 1024 (default: the machine's cores); the "
                    "report is the same for every count; 1 runs everything on one thread, 2 and "
                    "more run the independent ops of a command in parallel")
        ->check(whole_number_from(1, 1024, "a thread count"));
    add_max_raw_option(sub, &args->reader);
    sub->footer(
        "Environment: CLASTRACE_ENGINE_SIMD=sse traces with the engine's 4-wide SSE path where the "
        "CPU has AVX2 (the reference path; same hits); CLASTRACE_REPLAY_RUN_AHEAD=0 runs every "
        "cluster build in its turn (by default they run ahead of their turn from 2 threads, "
        "and hazards are checked on a thread of their own with them); "
        "CLASTRACE_REPLAY_SYNC_THREAD=0 keeps the hazard checks on the replay thread, =1 asks "
        "for their thread without runs ahead (docs/replay.md \"Threads\").");
    return Command{sub, [args] { return run_replay(*args); }};
}

}  // namespace clastrace::tools
