// SPDX-License-Identifier: Apache-2.0
#include "stored_text.h"

#include <clastrace/traces/utf8_text.h>

#include <string_view>

namespace clastrace::traces {

namespace {

void repair(std::string& text) {
    if (!is_valid_utf8(text)) text = valid_utf8(text);
}

bool invalid(const flatbuffers::String* text) {
    return text && !is_valid_utf8(std::string_view(text->c_str(), text->size()));
}

}  // namespace

void make_strings_valid_utf8(fbs::TraceHeaderT& header) {
    if (fbs::DeviceInfoT* d = header.device.get()) {
        repair(d->name);
        repair(d->driver_name);
        repair(d->driver_info);
        for (std::string& extension : d->enabled_extensions) repair(extension);
    }
    if (fbs::CaptureSettingsT* c = header.capture.get()) {
        repair(c->application_name);
        repair(c->engine_name);
        repair(c->capture_tool);
        repair(c->snapshot_policy);
    }
}

// The record kinds with strings; the two functions below list the same fields.
bool has_invalid_utf8(const fbs::Record& record) {
    using fbs::RecordBody;
    switch (record.body_type()) {
    case RecordBody::CpuTimestamp: {
        const auto* t = record.body_as_CpuTimestamp();
        return t && invalid(t->label());
    }
    case RecordBody::DebugLabel: {
        const auto* l = record.body_as_DebugLabel();
        return l && invalid(l->text());
    }
    case RecordBody::RayQueryCheck: {
        const auto* c = record.body_as_RayQueryCheck();
        return c && invalid(c->label());
    }
    case RecordBody::CaptureFinding: {
        const auto* f = record.body_as_CaptureFinding();
        return f && (invalid(f->rule()) || invalid(f->message()));
    }
    case RecordBody::CmdDraw: {
        const auto* d = record.body_as_CmdDraw();
        return d && invalid(d->entry_point());
    }
    case RecordBody::CmdTraceRays: {
        const auto* t = record.body_as_CmdTraceRays();
        return t && invalid(t->entry_point());
    }
    default: return false;
    }
}

void make_strings_valid_utf8(fbs::RecordT& record) {
    using fbs::RecordBody;
    switch (record.body.type) {
    case RecordBody::CpuTimestamp:
        if (auto* t = record.body.AsCpuTimestamp()) repair(t->label);
        break;
    case RecordBody::DebugLabel:
        if (auto* l = record.body.AsDebugLabel()) repair(l->text);
        break;
    case RecordBody::RayQueryCheck:
        if (auto* c = record.body.AsRayQueryCheck()) repair(c->label);
        break;
    case RecordBody::CaptureFinding:
        if (auto* f = record.body.AsCaptureFinding()) {
            repair(f->rule);
            repair(f->message);
        }
        break;
    case RecordBody::CmdDraw:
        if (auto* d = record.body.AsCmdDraw()) repair(d->entry_point);
        break;
    case RecordBody::CmdTraceRays:
        if (auto* t = record.body.AsCmdTraceRays()) repair(t->entry_point);
        break;
    default: break;
    }
}

}  // namespace clastrace::traces
