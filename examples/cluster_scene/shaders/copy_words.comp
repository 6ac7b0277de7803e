// SPDX-License-Identifier: Apache-2.0
// cluster_scene --compute-infos: copies `words` 32-bit words from `source` to `target`, and one
// word (the count) from `count_source` to `count_target`, all reached through buffer device
// addresses given in push constants (GL_EXT_buffer_reference), as real cluster renderers write
// their src infos and counts from compute. No descriptor names any of them, so only a capture
// that follows device addresses sees the writes.
#version 460
#extension GL_EXT_buffer_reference : require

layout(local_size_x = 64) in;

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer SourceWords {
    uint words[];
};
layout(buffer_reference, std430, buffer_reference_align = 4) writeonly buffer TargetWords {
    uint words[];
};

layout(push_constant) uniform Copy {
    SourceWords source;
    TargetWords target;
    SourceWords count_source;
    TargetWords count_target;
    uint words;
} copy_info;

void main() {
    const uint i = gl_GlobalInvocationID.x;
    if (i < copy_info.words) copy_info.target.words[i] = copy_info.source.words[i];
    if (i == 0) copy_info.count_target.words[0] = copy_info.count_source.words[0];
}
