// The whole package: the model layer's public headers and the unroll job link and run.
#include <vkunroll/host/model/weights.hpp>
#include <vkunroll/host/unroll/unroll.hpp>
#include <vkunroll/runtime/context.hpp>
#include <iostream>
int main() {
  auto l = vkunroll::Context::enumerate();
  const auto cfg = vkunroll::ModelConfig::published();
  std::cout << l.devices.size() << " device(s), published model " << vkunroll::parameter_count(cfg) << " parameters\n";
}
