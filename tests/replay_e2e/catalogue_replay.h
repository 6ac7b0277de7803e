// SPDX-License-Identifier: Apache-2.0
// A catalogue scene end to end: written with TraceScript over the catalogue's buffers, replayed
// and removed (CLASTRACE_KEEP_TRACES=1 keeps it).
#pragma once

#include "catalogue_scene.h"
#include "trace_files.h"
#include "trace_script.h"

#include <string>

namespace clastrace::test::catalogue {

// `write(TraceScript&)` records the scene's commands; the trace is submitted and finished after.
template <class Write>
replay::ReplayReport replay_catalogue_scene(const std::string& path, Write&& write) {
    {
        TraceScript t(path, device());
        add_buffers(t);
        write(t);
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    discard_trace(path);
    return r;
}

}  // namespace clastrace::test::catalogue
