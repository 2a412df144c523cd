/* volk ships as source in Debian's libvulkan-volk-dev: compile it once, here. */
#include <volk.c>
