// SPDX-License-Identifier: Apache-2.0
// clastrace analyze TRACE [--json | --html OUT.html]: replays the trace and, as each command
// is replayed, folds it into a report of where the memory and time of its
// acceleration-structure builds go (docs/analyze.md).
#include "commands.h"
#include "reader_options.h"
#include "trace_error_json.h"

#include <clastrace/analyze/analyzer.h>
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/analyze/report_output.h>
#include <clastrace/traces/trace_reader.h>

#include <cstdio>
#include <memory>
#include <string>

namespace clastrace::tools {

namespace {

struct AnalyzeArgs {
    std::string trace;
    bool json = false;
    std::string html;
    uint32_t truncation_rebuilds = 8;
    traces::TraceReaderOptions reader{.verify_content_keys = true};
};

int run_analyze(const AnalyzeArgs& args) {
    traces::TraceError error;
    std::unique_ptr<traces::TraceReader> reader =
        traces::TraceReader::open(args.trace, &error, args.reader);
    if (!reader) {
        if (args.json) {
            print_trace_error_json(args.trace, error);
        } else {
            std::fprintf(stderr, "clastrace analyze: %s\n", error.message.c_str());
        }
        return kExitUsage;
    }
    analyze::TraceAnalysis analysis;
    try {
        analyze::AnalyzeOptions options;
        options.stream.untruncated_rebuilds_per_command = args.truncation_rebuilds;
        analysis = analyze::analyze_trace(*reader, args.trace, options);
    } catch (const analyze::AnalysisInputError& e) {
        std::fprintf(stderr, "clastrace analyze: %s: the replay could not be analyzed: %s\n",
                     args.trace.c_str(), e.what());
        return kExitUsage;
    }
    const analyze::AnalysisReport& report = analysis.report;
    const analyze::ReportFormat format = args.json           ? analyze::ReportFormat::kJson
                                         : args.html.empty() ? analyze::ReportFormat::kText
                                                             : analyze::ReportFormat::kHtml;
    std::string write_error;
    if (!analyze::write_report(report, format, args.html, &write_error)) {
        std::fprintf(stderr, "clastrace analyze: %s\n", write_error.c_str());
        return kExitUsage;
    }
    if (!args.html.empty() && args.html != "-")
        std::fprintf(stdout, "report written to %s\n", args.html.c_str());
    return analysis.replay.clean() && report.hazards_total == 0 ? kExitOk : kExitFindings;
}

}  // namespace

Command register_analyze(CLI::App& app) {
    auto args = std::make_shared<AnalyzeArgs>();
    CLI::App* sub = app.add_subcommand("analyze",
                                       "Replay a trace and report object sizes (engine vs driver) "
                                       "per op type, hazards and timing, as text, "
                                       "JSON or one self-contained HTML file. Exit: 0 clean (the "
                                       "replay's notes on its own limits allowed), 1 hazards or "
                                       "findings, 2 usage error or unreadable trace.");
    sub->add_option("TRACE", args->trace, "the .clt trace")->required();
    CLI::Option* json = sub->add_flag("--json", args->json,
                                      "print the report as one JSON object (docs/analyze.md)");
    CLI::Option* html =
        sub->add_option("--html", args->html, "write the report as a self-contained HTML file");
    sub->add_option("--truncation-rebuilds", args->truncation_rebuilds,
                    "truncated clusters per command rebuilt at positionTruncateBitCount 0 to "
                    "measure what truncation "
                    "saves (one more engine build each; 0: none)")
        ->capture_default_str();
    add_max_raw_option(sub, &args->reader);
    json->excludes(html);
    html->excludes(json);
    return Command{sub, [args] { return run_analyze(*args); }};
}

}  // namespace clastrace::tools
