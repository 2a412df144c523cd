#include <vkunroll/runtime/context.hpp>
#include <iostream>
int main() { auto l = vkunroll::Context::enumerate(); std::cout << l.devices.size() << " device(s)\n"; }
