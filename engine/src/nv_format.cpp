// SPDX-License-Identifier: Apache-2.0
// Sizes and the one-pass check of an NV object's bytes.
#include "clastrace/engine/nv_format.h"

#include <cstring>

namespace clastrace::engine {
namespace {

uint64_t align_up(uint64_t v, uint64_t a) { return (v + a - 1) / a * a; }

template <class T>
T load(std::span<const std::byte> bytes, uint64_t offset) {
    T value;
    std::memcpy(&value, bytes.data() + offset, sizeof(T));
    return value;
}

bool section_fits(uint64_t offset, uint64_t count, uint64_t element, uint64_t size) {
    if (offset > size) return false;
    if (count == 0) return true;
    if (count > (size - offset) / element) return false;
    return true;
}

}  // namespace

uint64_t nv_node_bound(uint64_t items) { return items == 0 ? 0 : 2 * items - 1; }

NvMemoryRequirements nv_memory_requirements(bool top_level, uint64_t geometry_count,
                                            uint64_t count) {
    NvMemoryRequirements r;
    const uint64_t records =
        top_level ? count * sizeof(NvInstanceRecord) : count * sizeof(NvPrimitiveRecord);
    const uint64_t geometries = top_level ? 0 : geometry_count * sizeof(NvGeometryRecord);
    r.object = align_up(sizeof(NvObjectHeader) + geometries + records +
                            nv_node_bound(count) * sizeof(NvNode),
                        kNvObjectAlignment);
    // The builder's working set: per item a box, a centroid and an index (32 B); the
    // refit keeps one flag per node.
    r.build_scratch = align_up(count * 32 + 256, kNvObjectAlignment);
    r.update_scratch = align_up(nv_node_bound(count) * 4 + 256, kNvObjectAlignment);
    return r;
}

std::optional<NvObjectHeader> read_nv_header(std::span<const std::byte> bytes, std::string* error) {
    auto fail = [&](const std::string& why) -> std::optional<NvObjectHeader> {
        if (error) *error = why;
        return std::nullopt;
    };
    if (bytes.size() < sizeof(NvObjectHeader))
        return fail("fewer than 96 bytes: no NV object header");
    NvObjectHeader h = load<NvObjectHeader>(bytes, 0);
    if (h.magic != kNvObjectMagic)
        return fail("magic is not the engine's NV object magic (never built, or overwritten)");
    if (h.kind != uint8_t(NvObjectKind::kBottomLevel) && h.kind != uint8_t(NvObjectKind::kTopLevel))
        return fail("object kind " + std::to_string(h.kind) +
                    " is neither bottom (1) nor top level (2)");
    if (h.format_version != kNvFormatVersion)
        return fail("format version " + std::to_string(h.format_version) + " unknown");
    if (h.object_size < sizeof(NvObjectHeader)) return fail("object_size below the header size");
    return h;
}

std::optional<NvObjectView> open_nv_object(std::span<const std::byte> bytes, std::string* error) {
    auto fail = [&](const std::string& why) -> std::optional<NvObjectView> {
        if (error) *error = why;
        return std::nullopt;
    };
    std::optional<NvObjectHeader> h = read_nv_header(bytes, error);
    if (!h) return std::nullopt;
    if (h->object_size > bytes.size())
        return fail("object_size " + std::to_string(h->object_size) + " runs past the " +
                    std::to_string(bytes.size()) + " bytes available");
    const uint64_t size = h->object_size;
    const bool top = h->kind == uint8_t(NvObjectKind::kTopLevel);
    if (top && h->geometry_count != 0) return fail("top-level object with geometries");
    if (!section_fits(h->geometries_offset, h->geometry_count, sizeof(NvGeometryRecord), size))
        return fail("geometry records run past the object");
    const uint64_t record = top ? sizeof(NvInstanceRecord) : sizeof(NvPrimitiveRecord);
    if (!section_fits(h->primitives_offset, h->primitive_count, record, size))
        return fail("primitive/instance records run past the object");
    if (!section_fits(h->nodes_offset, h->node_count, sizeof(NvNode), size))
        return fail("nodes run past the object");
    if (h->node_count > nv_node_bound(h->primitive_count))
        return fail("more nodes than a tree over its records can have");
    NvObjectView view{bytes.first(size), *h};
    for (uint32_t i = 0; i < h->node_count; ++i) {
        const NvNode n = view.node(i);
        if (n.count == 0) {
            if (uint64_t(i) + 1 >= h->node_count || n.first <= i + 1 || n.first >= h->node_count)
                return fail("node " + std::to_string(i) +
                            " has a child index out of order or out of range");
        } else if (n.count > kNvMaxLeafSize || uint64_t(n.first) + n.count > h->primitive_count) {
            return fail("leaf node " + std::to_string(i) + " covers records past primitive_count");
        }
    }
    if (!top) {
        for (uint32_t i = 0; i < h->primitive_count; ++i)
            if (view.primitive(i).geometry_index >= h->geometry_count)
                return fail("primitive record " + std::to_string(i) + " names geometry " +
                            std::to_string(view.primitive(i).geometry_index) + " of " +
                            std::to_string(h->geometry_count));
    }
    return view;
}

NvGeometryRecord NvObjectView::geometry(uint32_t i) const {
    return load<NvGeometryRecord>(bytes, header.geometries_offset +
                                             uint64_t(i) * sizeof(NvGeometryRecord));
}
NvPrimitiveRecord NvObjectView::primitive(uint32_t i) const {
    return load<NvPrimitiveRecord>(bytes, header.primitives_offset +
                                              uint64_t(i) * sizeof(NvPrimitiveRecord));
}
NvInstanceRecord NvObjectView::instance(uint32_t i) const {
    return load<NvInstanceRecord>(bytes, header.primitives_offset +
                                             uint64_t(i) * sizeof(NvInstanceRecord));
}
NvNode NvObjectView::node(uint32_t i) const {
    return load<NvNode>(bytes, header.nodes_offset + uint64_t(i) * sizeof(NvNode));
}

}  // namespace clastrace::engine
