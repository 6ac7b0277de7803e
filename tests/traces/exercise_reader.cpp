// SPDX-License-Identifier: Apache-2.0
#include "exercise_reader.h"

#include <clastrace/traces/records.h>

#include <vector>

namespace clastrace::traces::testing {

ExerciseResult exercise_reader(const uint8_t* data, size_t size) {
    ExerciseResult result;
    TraceError error;
    auto reader = TraceReader::open_memory(data, size, "fuzz.clt", &error);
    if (!reader) {
        if (!error) __builtin_trap();  // a refusal must say why
        return result;
    }
    result.opened = true;
    if (const fbs::TraceHeader* h = reader->header()) {
        if (h->device() && h->device()->name()) (void)h->device()->name()->size();
    }
    std::vector<uint64_t> hashes;
    RecordView v;
    while (reader->next(&v)) {
        ++result.records;
        SnapshotLists lists = record_snapshots(*v.record);
        if (lists.inputs && lists.inputs->size() > 0 && hashes.size() < 8)
            hashes.push_back(lists.inputs->Get(0)->hash());
    }
    std::vector<uint8_t> bytes;
    for (uint64_t h : hashes) (void)reader->read_contents(h, &bytes);
    uint64_t submissions = reader->indexed_submission_count();
    for (uint64_t k : {uint64_t{0}, submissions / 2, submissions + 1}) {
        if (!reader->seek_to_submission(k)) {
            int n = 0;
            while (n++ < 16 && reader->next(&v)) {}
        }
    }
    result.damage = reader->damage_count();
    return result;
}

}  // namespace clastrace::traces::testing
