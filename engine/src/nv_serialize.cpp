// SPDX-License-Identifier: Apache-2.0
// Serialization of NV objects and the checks of a deserialization (nv_serialize.h).
#include "clastrace/engine/nv_serialize.h"
#include "clastrace/common/hex.h"

#include <cstring>

namespace clastrace::engine {
namespace {

using common::hex;

constexpr VkPipelineStageFlags2 kStageCopy =
    VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR;

void add_finding(NvDeserializeResult& r, const char* rule, std::string message,
                 uint64_t address = 0) {
    r.record.findings.push_back(Finding{rule, std::move(message), -1, address});
}

}  // namespace

std::vector<std::byte> serialize_nv_object(const MemoryImage& memory, uint64_t address,
                                           std::string* error) {
    std::vector<std::byte> object;
    try {
        auto head = memory.read_bytes(address, sizeof(NvObjectHeader),
                                      FieldRef{"acceleration structure", -1});
        auto h = read_nv_header(head, error);
        if (!h) return {};
        auto bytes =
            memory.read_bytes(address, h->object_size, FieldRef{"acceleration structure", -1});
        object.assign(bytes.begin(), bytes.end());
    } catch (const MemoryFault& f) {
        if (error) *error = f.message;
        return {};
    }
    auto view = open_nv_object(object, error);
    if (!view) return {};
    const bool top = view->header.kind == uint8_t(NvObjectKind::kTopLevel);
    std::vector<uint64_t> handles;
    if (top) {
        handles.resize(view->header.primitive_count);
        for (uint32_t i = 0; i < view->header.primitive_count; ++i) {
            NvInstanceRecord r = view->instance(i);
            handles[i] = r.active ? r.reference : 0;
            r.blas_address = 0;  // position independent: the handle list carries the reference
            std::memcpy(object.data() + view->header.primitives_offset +
                            uint64_t(i) * sizeof(NvInstanceRecord),
                        &r, sizeof r);
        }
    }
    SerializedHeader sh{};
    std::memcpy(sh.driver_uuid, kEngineDriverUuid.data(), 16);
    std::memcpy(sh.compatibility_uuid, kEngineNvCompatibilityUuid.data(), 16);
    sh.handle_count = handles.size();
    sh.deserialized_size = object.size();
    sh.serialized_size = sizeof sh + handles.size() * 8 + object.size();
    std::vector<std::byte> out(sh.serialized_size);
    std::memcpy(out.data(), &sh, sizeof sh);
    if (!handles.empty()) std::memcpy(out.data() + sizeof sh, handles.data(), handles.size() * 8);
    std::memcpy(out.data() + sizeof sh + handles.size() * 8, object.data(), object.size());
    return out;
}

namespace {

// The engine's own blob: decode, check, patch handles, write the object to dst.
void deserialize_engine_blob(const NvDeserializeCommand& cmd, MemoryImage& memory,
                             const NvDeserializeOptions& options, std::span<const std::byte> blob,
                             NvDeserializeResult& r) {
    const SerializedHeader& h = r.header;
    const uint64_t object_offset = sizeof h + h.handle_count * 8;
    if (h.serialized_size - object_offset != h.deserialized_size) {
        add_finding(r, kVuidDeserializeContents,
                    "serializedSize " + std::to_string(h.serialized_size) + " is not the header, " +
                        std::to_string(h.handle_count) + " handles and deserializedSize " +
                        std::to_string(h.deserialized_size),
                    cmd.src_address);
        return;
    }
    std::vector<std::byte> object(blob.begin() + object_offset, blob.end());
    std::string error;
    auto view = open_nv_object(object, &error);
    if (!view || view->header.object_size != object.size()) {
        add_finding(r, kVuidDeserializeContents,
                    "the serialized object at " + hex(cmd.src_address + object_offset) +
                        " is damaged: " +
                        (view ? "object_size differs from deserializedSize" : error),
                    cmd.src_address + object_offset);
        return;
    }
    r.top_level = view->header.kind == uint8_t(NvObjectKind::kTopLevel);
    const uint64_t expected_handles = r.top_level ? view->header.primitive_count : 0;
    if (h.handle_count != expected_handles) {
        add_finding(r, kVuidDeserializeContents,
                    "handleCount " + std::to_string(h.handle_count) + " differs from the " +
                        std::to_string(expected_handles) + " instance records of the object",
                    cmd.src_address);
        return;
    }
    if (cmd.dst.created &&
        (cmd.dst.created->type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV) != r.top_level)
        add_finding(r, kRuleDeserializeTypeDiffers,
                    std::string("the serialized object is ") + (r.top_level ? "top" : "bottom") +
                        "-level; dst " + hex(cmd.dst.handle) + " was created as the other level",
                    cmd.dst.address);
    for (uint32_t i = 0; r.top_level && i < expected_handles; ++i) {
        const uint64_t at = view->header.primitives_offset + uint64_t(i) * sizeof(NvInstanceRecord);
        NvInstanceRecord rec = view->instance(i);
        rec.reference = r.handles[i];
        rec.active = rec.reference != 0;
        rec.blas_address = 0;
        if (rec.active) {
            std::optional<uint64_t> a = options.resolve_handle
                                            ? options.resolve_handle(rec.reference)
                                            : std::optional<uint64_t>(rec.reference);
            if (a)
                rec.blas_address = *a;
            else
                add_finding(
                    r, kRuleDeserializeHandleUnknown,
                    "handle " + std::to_string(i) + " (" + hex(rec.reference) +
                        ") names no acceleration structure created before the deserialization",
                    cmd.src_address + sizeof h + 8ull * i);
        }
        std::memcpy(object.data() + at, &rec, sizeof rec);
    }
    try {
        auto out = memory.write_bytes(cmd.dst.address, object.size(), FieldRef{"pInfo->dst", -1});
        std::memcpy(out.data(), object.data(), object.size());
    } catch (const MemoryFault& f) {
        add_finding(r, kVuidDeserializeDstBound,
                    "dst's memory cannot hold the object: " + f.message, cmd.dst.address);
        return;
    }
    r.record.ops[0].executed = true;
    r.record.ops[0].dst_address = cmd.dst.address;
    r.record.ops[0].dst_size = object.size();
}

}  // namespace

NvDeserializeResult execute_nv_deserialize(const NvDeserializeCommand& cmd, MemoryImage& memory,
                                           const NvDeserializeOptions& options) {
    NvDeserializeResult r;
    r.record.op_count = 1;
    r.record.ops.resize(1);
    if (cmd.mode != VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR) {
        add_finding(r, kVuidDeserializeMode,
                    "pInfo->mode is " + std::to_string(cmd.mode) +
                        ", not VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR");
        return r;
    }
    if (cmd.src_address % kSerializedAlignment)
        add_finding(r, kVuidDeserializeSrcAlign,
                    "pInfo->src.deviceAddress " + hex(cmd.src_address) +
                        " is not a multiple of 256",
                    cmd.src_address);
    if (!memory.find_region(cmd.src_address)) {
        add_finding(r, kVuidDeserializeSrcAddress,
                    "pInfo->src.deviceAddress " + hex(cmd.src_address) +
                        " lies in no buffer bound to memory",
                    cmd.src_address);
        return r;
    }
    if (cmd.dst.handle == 0 || !cmd.dst.bound) {
        add_finding(r, kVuidDeserializeDstBound,
                    "pInfo->dst " + hex(cmd.dst.handle) + " has no memory bound");
        return r;
    }
    const FieldRef src_field{"pInfo->src.deviceAddress", -1};
    try {
        r.header = memory.read<SerializedHeader>(cmd.src_address, src_field);
    } catch (const MemoryFault& f) {
        add_finding(r, kRuleDeserializeSrcPastBuffer,
                    "the 56-byte serialization header at " + hex(cmd.src_address) +
                        " runs past the end of its buffer: " + f.message,
                    cmd.src_address);
        return r;
    }
    r.header_read = true;
    const SerializedHeader& h = r.header;
    const uint64_t src_used = std::max<uint64_t>(h.serialized_size, sizeof h);
    // The header's own sizes must agree before anything they count is read.
    if (h.handle_count > (~0ull - sizeof h) / 8 ||
        h.serialized_size < sizeof h + h.handle_count * 8) {
        add_finding(r, kVuidDeserializeContents,
                    "serialization header at " + hex(cmd.src_address) + ": handleCount " +
                        std::to_string(h.handle_count) + " does not fit serializedSize " +
                        std::to_string(h.serialized_size),
                    cmd.src_address);
        return r;
    }
    std::span<const std::byte> blob;
    try {
        blob = memory.read_bytes(cmd.src_address, h.serialized_size, src_field);
    } catch (const MemoryFault& f) {
        add_finding(r, kRuleDeserializeSrcPastBuffer,
                    "serializedSize " + std::to_string(h.serialized_size) + " at " +
                        hex(cmd.src_address) + " runs past the end of its buffer: " + f.message,
                    cmd.src_address);
        return r;
    }
    r.record.accesses.push_back(MemoryAccess{cmd.src_address, cmd.src_address + src_used,
                                             kStageCopy, VK_ACCESS_2_TRANSFER_READ_BIT, false,
                                             "pInfo->src.deviceAddress", -1});
    r.handles.resize(h.handle_count);
    if (h.handle_count) std::memcpy(r.handles.data(), blob.data() + sizeof h, h.handle_count * 8);
    if (h.deserialized_size > cmd.dst.size) {
        add_finding(r, kVuidDeserializeDstSize,
                    "deserializedSize " + std::to_string(h.deserialized_size) + " is above the " +
                        std::to_string(cmd.dst.size) + " bytes dst " + hex(cmd.dst.handle) +
                        " was created with",
                    cmd.dst.address);
        return r;
    }
    const uint64_t dst_end = cmd.dst.address + std::max<uint64_t>(h.deserialized_size, 1);
    if (cmd.src_address < dst_end && cmd.dst.address < cmd.src_address + src_used)
        add_finding(r, kRuleDeserializeOverlap,
                    "the serialized data at " + hex(cmd.src_address) +
                        " overlaps dst's memory at " + hex(cmd.dst.address),
                    std::max(cmd.src_address, cmd.dst.address));
    r.record.accesses.push_back(MemoryAccess{cmd.dst.address, dst_end, kStageCopy,
                                             kAccessObjectWrite, true, "pInfo->dst", -1});
    const bool engine_blob =
        std::memcmp(h.driver_uuid, kEngineDriverUuid.data(), 16) == 0 &&
        std::memcmp(h.compatibility_uuid, kEngineNvCompatibilityUuid.data(), 16) == 0;
    if (!engine_blob) {
        r.opaque = true;
        const bool device_own =
            options.device_compatibility_uuid &&
            std::memcmp(h.compatibility_uuid, options.device_compatibility_uuid->data(), 16) == 0;
        add_finding(r, kRuleSerializedOpaque,
                    "the serialized data at " + hex(cmd.src_address) +
                        " carries another driver's UUIDs: its " +
                        std::to_string(h.deserialized_size) +
                        "-byte object cannot be decoded; header sizes and handles were checked",
                    cmd.src_address);
        if (options.device_compatibility_uuid && !device_own)
            add_finding(r, kVuidDeserializeCompatible,
                        "the serialized data's compatibility UUID is neither the capturing "
                        "device's nor the engine's",
                        cmd.src_address);
        return r;
    }
    deserialize_engine_blob(cmd, memory, options, blob, r);
    return r;
}

}  // namespace clastrace::engine
