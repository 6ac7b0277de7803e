// SPDX-License-Identifier: Apache-2.0
// Tests that read a trace keep the records they check as FlatBuffers object-API copies, which
// outlive the reader's chunk: one helper instead of a switch case per kind in every test.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/traces/trace_reader.h>

#include <vector>

namespace clastrace::testsupport {

// When `view` is a `Table` record, appends its unpacked copy to `out` and returns it.
template <typename Table>
typename Table::NativeTableType* unpack_record(const traces::RecordView& view,
                                               std::vector<typename Table::NativeTableType>& out) {
    if (view.kind != fbs::RecordBodyTraits<Table>::enum_value) return nullptr;
    out.emplace_back();
    view.record->template body_as<Table>()->UnPackTo(&out.back());
    return &out.back();
}

}  // namespace clastrace::testsupport
