// The session's options that apply to one backend only, in one table (unroll_options.cpp,
// kVulkanOnlyOptions): precision fp16, device, conv_choice, profile and trace apply to the Vulkan
// backend. With backend cpu each is refused (OptionError naming it), never ignored; the unroll job
// (validate_unroll_options: the CLI) and UnrollSession (Python) both check it.
#pragma once
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

void check_session_options_apply(const SessionOptions& o);

}  // namespace vkunroll
