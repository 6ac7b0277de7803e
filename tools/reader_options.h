// SPDX-License-Identifier: Apache-2.0
// The reader options that `info`, `replay` and `analyze` share on their command lines.
#pragma once

#include "whole_number_option.h"

#include <clastrace/traces/trace_reader.h>

#include <CLI/CLI.hpp>

#include <cstdint>

namespace clastrace::tools {

// --max-raw-mib: raises the decompression budget (TraceReaderOptions::max_raw_bytes) for a
// real trace that inflates more than 1024 times its file size. At most what fits in bytes.
inline void add_max_raw_option(CLI::App* command, traces::TraceReaderOptions* options) {
    command
        ->add_option_function<uint64_t>(
            "--max-raw-mib", [options](uint64_t mib) { options->max_raw_bytes = mib << 20; },
            "MiB the reader may decompress in all (default: 1024 x the file size, at least 4096); "
            "a trace that "
            "inflates past it is reported as damaged")
        ->check(whole_number_from(1, UINT64_MAX >> 20, "the MiB the reader may decompress"));
}

}  // namespace clastrace::tools
