// SPDX-License-Identifier: Apache-2.0
// Fuzz target: arbitrary bytes through the pass `clastrace info` makes (tools/cmd_info.cpp,
// not a library): a reader that re-hashes every content against its key, every record read
// and the strings info prints touched, every snapshot's contents fetched.
#include "fuzz_trace_name.h"

#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>

#include <string>
#include <vector>

using namespace clastrace;

namespace {

size_t touch(const flatbuffers::String* s) {
    return s ? std::string(s->c_str(), s->size()).size() : 0;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    traces::TraceError error;
    auto reader =
        traces::TraceReader::open_memory(data, size, kFuzzTraceName, &error,
                                         traces::TraceReaderOptions{.verify_content_keys = true});
    if (!reader) {
        if (!error) __builtin_trap();  // a refusal must say why
        return 0;
    }
    size_t text = 0;
    if (const fbs::TraceHeader* h = reader->header()) {
        if (const auto* d = h->device())
            text += touch(d->name()) + touch(d->driver_name()) + touch(d->driver_info());
        if (const auto* c = h->capture())
            text += touch(c->application_name()) + touch(c->engine_name());
    }
    std::vector<uint64_t> hashes;
    traces::RecordView view;
    while (reader->next(&view)) {
        if (const auto* f = view.record->body_as_CaptureFinding())
            text += touch(f->rule()) + touch(f->message());
        traces::SnapshotLists lists = traces::record_snapshots(*view.record);
        for (const traces::SnapshotVector* list : {lists.inputs, lists.outputs}) {
            if (!list) continue;
            for (const auto* snap : *list)
                if (hashes.size() < 64) hashes.push_back(snap->hash());
        }
    }
    std::vector<uint8_t> bytes;
    for (uint64_t h : hashes) (void)reader->read_contents(h, &bytes);
    for (const traces::TraceError& e : reader->damage())
        if (!e || e.message.empty()) __builtin_trap();  // damage names its rule
    (void)text;
    return 0;
}
