// SPDX-License-Identifier: Apache-2.0
// clastrace-make-sample [OUT]: regenerates traces/samples/sample.clt (default: ./sample.clt).
#include "sample_scene.h"

#include <cstdio>

int main(int argc, char** argv) {
    if (argc > 2 ||
        (argc == 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h"))) {
        std::printf(
            "usage: clastrace-make-sample [OUT.clt]\nWrites the sample trace (default "
            "./sample.clt).\n");
        return argc > 2 ? 2 : 0;
    }
    std::string out = argc == 2 ? argv[1] : "sample.clt";
    if (clastrace::traces::TraceError e = clastrace::samples::write_sample_trace(out)) {
        std::fprintf(stderr, "clastrace-make-sample: %s\n", e.message.c_str());
        return 1;
    }
    std::printf("wrote %s\n", out.c_str());
    return 0;
}
