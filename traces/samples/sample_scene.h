// SPDX-License-Identifier: Apache-2.0
// The scene of traces/samples/sample.clt: a small, realistic capture built with the
// writer API, standing in for a real capture until the capture layer exists.
#pragma once

#include <clastrace/traces/trace_error.h>

#include <string>

namespace clastrace::samples {

// Writes the sample trace to `path`.
traces::TraceError write_sample_trace(const std::string& path);

}  // namespace clastrace::samples
