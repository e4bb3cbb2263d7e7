# How every example makefile finds an installed libfap (included by
# examples/*/Makefile; one convention for all of them):
#
#   make                      pkg-config's fap.pc when pkg-config knows it
#                             (PKG_CONFIG_PATH=PREFIX/lib/<multiarch>/pkgconfig
#                             for a non-default prefix)
#   make PREFIX=/opt/libfap   no pkg-config: meson's install layout under PREFIX,
#                             headers in PREFIX/include/libfap and the library in
#                             PREFIX/lib/<multiarch> (Debian, Ubuntu: what meson
#                             picks, e.g. lib/x86_64-linux-gnu), else PREFIX/lib;
#                             LIBDIR=... overrides the library directory.
#
# Giving PREFIX (or LIBDIR) on the command line always uses the second way.
PKG_CONFIG ?= pkg-config
CFLAGS ?= -O2 -Wall -Wextra -Werror

ifeq ($(origin PREFIX)$(origin LIBDIR),undefinedundefined)
LIBFAP_PC := $(shell $(PKG_CONFIG) --exists fap 2>/dev/null && echo yes)
endif

ifeq ($(LIBFAP_PC),yes)
CPPFLAGS += $(shell $(PKG_CONFIG) --cflags fap)
LDLIBS   += $(shell $(PKG_CONFIG) --libs fap) -lpthread -lrt
else
PREFIX    ?= /usr/local
MULTIARCH := $(shell $(CC) -print-multiarch 2>/dev/null)
LIBDIR    ?= $(if $(and $(MULTIARCH),$(wildcard $(PREFIX)/lib/$(MULTIARCH))),$(PREFIX)/lib/$(MULTIARCH),$(PREFIX)/lib)
CPPFLAGS  += -I$(PREFIX)/include/libfap
LDFLAGS   += -L$(LIBDIR) -Wl,-rpath,$(LIBDIR)
LDLIBS    += -lfap -lpthread -lrt
endif
