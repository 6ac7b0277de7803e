// SPDX-License-Identifier: Apache-2.0
#include "clastrace/replay/hazard_report.h"
#include "clastrace/common/hex.h"
#include "hazard_text.h"

#include <cinttypes>
#include <cstdio>

#include <nlohmann/json.hpp>

namespace clastrace::replay {
namespace {

using common::hex;

std::string where(const HazardAccess& a) { return command_place_text(a.command, a.queue, a.frame); }

const char* verb(const HazardAccess& a) { return a.is_write ? "writes" : "reads"; }
const char* past(const HazardAccess& a) { return a.is_write ? "wrote" : "read"; }

nlohmann::json side_json(const HazardAccess& a) {
    nlohmann::json j = {
        {"command", a.command.name ? a.command.name : ""},
        {"queue", a.queue == kHostQueue ? nlohmann::json("host") : nlohmann::json(a.queue)},
        {"submission", a.command.submission},
        {"command_buffer", a.command.command_buffer},
        {"command_buffer_handle", hex(a.command.command_buffer_handle)},
        {"command_index", a.command.command},
        {"field", a.field},
        {"stage", stage_names(a.stage)},
        {"access", access_names(a.access)},
        {"write", a.is_write},
        {"possible", a.possible},
        {"range", {hex(a.range.begin), hex(a.range.end)}},
    };
    if (a.frame) j["frame"] = *a.frame;
    if (a.command
            .secondary_handle)  // a command of a secondary command buffer (vkCmdExecuteCommands)
        j["secondary"] = {{"index", a.command.secondary},
                          {"command_buffer_handle", hex(a.command.secondary_handle)},
                          {"command_index", a.command.secondary_command}};
    return j;
}

const char* fix_kind_name(FixKind k) {
    switch (k) {
    case FixKind::kPipelineBarrier: return "pipeline_barrier";
    case FixKind::kSemaphore: return "semaphore";
    case FixKind::kHostWait: return "host_wait";
    case FixKind::kHostWaitAndBarrier: return "host_wait_and_barrier";
    case FixKind::kDisjointRanges: return "disjoint_ranges";
    }
    return "?";
}

}  // namespace

namespace {

const char* command_name(const CommandRef& command) {
    return command.name && *command.name ? command.name : "command";
}

// The words between a device command's parentheses; `handle` adds the command buffer's after
// its index.
std::string queue_place(const CommandRef& command, QueueId queue, std::optional<uint64_t> frame,
                        bool handle) {
    std::string s = "queue " + std::to_string(queue) + ", submit " +
                    std::to_string(command.submission) + ", cb " +
                    std::to_string(command.command_buffer);
    if (handle) s += " (" + hex(command.command_buffer_handle) + ")";
    s += ", cmd " + std::to_string(command.command);
    if (frame) s += ", frame " + std::to_string(*frame);
    if (command.secondary_handle)
        s += " > secondary " + std::to_string(command.secondary) + " (" +
             hex(command.secondary_handle) + "), cmd " + std::to_string(command.secondary_command);
    return s;
}

}  // namespace

std::string command_place_text(const CommandRef& command, QueueId queue,
                               std::optional<uint64_t> frame) {
    const std::string name = command_name(command);
    if (queue == kHostQueue) return name + " (host)";
    return name + " (" + queue_place(command, queue, frame, false) + ")";
}

std::string finding_place_text(const ReplayLocation& where) {
    const CommandRef command = command_ref(where);
    const std::string place = where.queue == kHostQueue
                                  ? "host, submit " + std::to_string(where.submission)
                                  : queue_place(command, where.queue, std::nullopt, true);
    return std::string(command_name(command)) + " (" + place + ") [#" +
           std::to_string(where.sequence) + "]";
}

std::string range_text(AddressRange range) {
    return "[" + hex(range.begin) + ", " + hex(range.end) + ")";
}

const char* hazard_class_name(HazardClass c) {
    switch (c) {
    case HazardClass::kReadAfterWrite: return "READ-AFTER-WRITE";
    case HazardClass::kWriteAfterWrite: return "WRITE-AFTER-WRITE";
    case HazardClass::kWriteAfterRead: return "WRITE-AFTER-READ";
    case HazardClass::kMoveOverlap: return "MOVE-OVERLAP";
    case HazardClass::kDeserializeInUse: return "DESERIALIZE-IN-USE";
    }
    return "?";
}

std::string FixingBarrier::describe() const {
    const std::string barrier = "{srcStageMask=" + stage_flag_names(src_stages) +
                                ", srcAccessMask=" + access_flag_names(src_access) +
                                ", dstStageMask=" + stage_flag_names(dst_stages) +
                                ", dstAccessMask=" + access_flag_names(dst_access) + "}";
    switch (kind) {
    case FixKind::kPipelineBarrier:
        return "vkCmdPipelineBarrier2 with a VkMemoryBarrier2 (or a VkBufferMemoryBarrier2 "
               "covering the range) " +
               barrier;
    case FixKind::kSemaphore:
        return "signal a semaphore after the earlier command (stageMask=" +
               stage_flag_names(src_stages) +
               ") and wait on it in the later submission with stageMask/pWaitDstStageMask "
               "including " +
               stage_flag_names(dst_stages);
    case FixKind::kHostWait:
        return "wait for the earlier submission's fence (vkWaitForFences or vkQueueWaitIdle) "
               "before the host access";
    case FixKind::kHostWaitAndBarrier:
        return "record vkCmdPipelineBarrier2 with a VkMemoryBarrier2 " + barrier +
               " after the earlier command, then wait for the submission's fence before the host "
               "reads";
    case FixKind::kDisjointRanges:
        return "no barrier can order a command against itself: use non-overlapping source and "
               "destination ranges";
    }
    return "";
}

std::string hazard_rule_name(const HazardReport& report) {
    return std::string(report.possible() ? "POSSIBLE-" : "") + "SYNC-HAZARD-" +
           hazard_class_name(report.hazard);
}

std::string HazardReport::format() const {
    std::string s = hazard_rule_name(*this) + ": ";
    const std::string region = range_text(overlap);
    if (hazard == HazardClass::kMoveOverlap) {
        s += where(later) + " copies " + prior.field + " " + range_text(prior.range) + " into " +
             later.field + " " + range_text(later.range) + ", which overlap in " + region + ".";
    } else {
        s += where(later) + " " + verb(later) + " " + later.field + " " + region + " at " +
             stage_names(later.stage) + " / " + access_names(later.access) + " after " +
             where(prior) + " " + past(prior) + " " + prior.field + " at " +
             stage_names(prior.stage) + " / " + access_names(prior.access);
        switch (fix.kind) {
        case FixKind::kSemaphore:
            s += " on another queue with no semaphore ordering them (a signal whose stage mask "
                 "holds the earlier"
                 " stage, waited on with a stage mask that holds the later one).";
            break;
        case FixKind::kHostWait:
        case FixKind::kHostWaitAndBarrier:
            if (later.queue == kHostQueue && later.is_write && prior.queue != kHostQueue)
                return s +
                       " with no completed host wait ordering the write after it: a HOST-WRITE "
                       "race (the host changed bytes a submission reads while it may still "
                       "run). Fix: wait on that submission's fence (vkWaitForFences) before "
                       "writing, or double-buffer (write a copy the submission does not read).";
            s += " with no completed host wait making it visible to the host.";
            break;
        default:
            s += hazard == HazardClass::kWriteAfterRead
                     ? " with no execution dependency between them."
                     : " with no barrier making it available and visible.";
        }
    }
    if (possible())
        s += " Possible, not certain: the dispatch's shader may write through buffer device "
             "addresses (its SPIR-V uses PhysicalStorageBuffer pointers), and the trace does not "
             "show which bytes it wrote.";
    s += " Fix: " + fix.describe();
    if (!advice.empty()) s += " " + advice;
    return s;
}

nlohmann::json to_json(const HazardReport& r) {
    return {
        {"class", hazard_class_name(r.hazard)},
        {"possible", r.possible()},
        {"prior", side_json(r.prior)},
        {"later", side_json(r.later)},
        {"overlap", {hex(r.overlap.begin), hex(r.overlap.end)}},
        {"fix",
         {{"kind", fix_kind_name(r.fix.kind)},
          {"srcStageMask", stage_flag_names(r.fix.src_stages)},
          {"srcAccessMask", access_flag_names(r.fix.src_access)},
          {"dstStageMask", stage_flag_names(r.fix.dst_stages)},
          {"dstAccessMask", access_flag_names(r.fix.dst_access)},
          {"text", r.fix.describe()},
          {"advice", r.advice}}},
        {"message", r.format()},
    };
}

nlohmann::json to_json(const std::vector<HazardReport>& reports, uint64_t suppressed) {
    nlohmann::json list = nlohmann::json::array();
    uint64_t possible = 0;
    for (const HazardReport& r : reports) {
        list.push_back(to_json(r));
        possible += r.possible() ? 1 : 0;
    }
    return {{"hazards", std::move(list)},
            {"certain", reports.size() - possible},
            {"possible", possible},
            {"suppressed", suppressed}};
}

namespace {

std::string without_size_note(const std::string& field) {
    return field.substr(0, field.find(" ("));
}

std::string size_note(const std::string& field) {
    const std::size_t at = field.find(" (");
    return at == std::string::npos ? std::string() : field.substr(at);
}

// "srcInfosArray[3].vertexBuffer" -> "srcInfosArray[*].vertexBuffer",
// "dstImplicitData[op 3]" -> "dstImplicitData[op *]".
std::string any_index(const std::string& field) {
    std::string out;
    for (std::size_t i = 0; i < field.size(); ++i) {
        out += field[i];
        if (field[i] != '[') continue;
        if (field.compare(i + 1, 3, "op ") == 0) {
            out += "op ";
            i += 3;
        }
        std::size_t j = i + 1;
        while (j < field.size() && field[j] >= '0' && field[j] <= '9') ++j;
        if (j > i + 1 && j < field.size() && field[j] == ']') {
            out += '*';
            i = j - 1;
        }
    }
    return out;
}

// "dstImplicitData[op *]" -> "dstImplicitData": an op's objects and the region's unpacked bytes
// are one field.
std::string without_op_index(const std::string& field) {
    std::string out = field;
    for (std::size_t at; (at = out.find("[op *]")) != std::string::npos;) out.erase(at, 6);
    return out;
}

}  // namespace

std::string hazard_field_family(const std::string& field) {
    return without_op_index(any_index(without_size_note(field)));
}

std::string folded_hazard_field(const std::string& a, const std::string& b) {
    if (a == b) return a;
    const std::string note = size_note(a).empty() ? size_note(b) : size_note(a);
    const std::string base_a = any_index(without_size_note(a));
    const std::string base_b = any_index(without_size_note(b));
    return (base_a == base_b ? base_a : without_op_index(base_a)) + note;
}

}  // namespace clastrace::replay
