# Installing hairfilter (cmake --install) and packaging it (cpack -G DEB).
#
#   bin/                       hairfilter, hairfilterd, hairfilter-load
#   lib/                       libhairfilter.so.<major> (+ .so), libhairfilter.a
#   lib/cmake/hairfilter/      find_package(hairfilter CONFIG): hairfilter::client
#                              (shared), hairfilter::client_static
#   lib/pkgconfig/             hairfilter.pc
#   include/hairfilter/        hairfilter.h, hairfilter.hpp, hairfilter_version.h
#   share/hairfilter/weights/  the bundled variants, their cards, hfnet.py
#   share/hairfilter/bench/    bench_torch.py (hairfilter bench --torch)
#   lib/systemd/system/        hairfilterd.service, paths set for the prefix
#   share/hairfilter/          hairfilterd.conf, the example config (same paths)
#   lib/python3/dist-packages/ the Python client (client/python)
#   share/doc/hairfilter/      LICENSE, CHANGELOG.md, README.md, copyright,
#                              SERVER.md, and what an engine integrating the
#                              client reads: CLIENT.md (client/lib/README.md),
#                              PROTOCOL.md and FEATURES.md (protocol/), which
#                              the headers cite
#
# Every file refers to the prefix relatively (the CMake package, the
# pkg-config file) or is written at install time (the service unit and its
# config file), so `cmake --install build --prefix DIR` gives a working tree
# anywhere.
include(CMakePackageConfigHelpers)

set(HF_CMAKE_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/hairfilter)
install(EXPORT hairfilterTargets NAMESPACE hairfilter:: DESTINATION ${HF_CMAKE_DIR}
        FILE hairfilterTargets.cmake)
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/hairfilterConfig.cmake.in
  ${PROJECT_BINARY_DIR}/hairfilterConfig.cmake INSTALL_DESTINATION ${HF_CMAKE_DIR})
# 0.x: a new minor version may change the API (CHANGELOG.md), so a request
# for 0.2 is met by 0.2.x only.
write_basic_package_version_file(${PROJECT_BINARY_DIR}/hairfilterConfigVersion.cmake
  VERSION ${PROJECT_VERSION} COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/hairfilterConfig.cmake
              ${PROJECT_BINARY_DIR}/hairfilterConfigVersion.cmake
        DESTINATION ${HF_CMAKE_DIR})

# pkg-config: the prefix relative to the .pc file's own folder.
set(HF_PC_DIR ${CMAKE_INSTALL_LIBDIR}/pkgconfig)
if(IS_ABSOLUTE "${CMAKE_INSTALL_LIBDIR}" OR IS_ABSOLUTE "${CMAKE_INSTALL_INCLUDEDIR}")
  set(HF_PC_PREFIX "${CMAKE_INSTALL_PREFIX}")
else()
  file(RELATIVE_PATH _rel /prefix/${HF_PC_DIR} /prefix)
  string(REGEX REPLACE "/$" "" _rel "${_rel}")
  set(HF_PC_PREFIX "\${pcfiledir}/${_rel}")
endif()
configure_file(${PROJECT_SOURCE_DIR}/cmake/hairfilter.pc.in ${PROJECT_BINARY_DIR}/hairfilter.pc @ONLY)
install(FILES ${PROJECT_BINARY_DIR}/hairfilter.pc DESTINATION ${HF_PC_DIR})

# Data the daemon and the CLI find beside their bin/ (cli_data_dir).
file(GLOB HF_WEIGHT_FILES ${PROJECT_SOURCE_DIR}/weights/*.safetensors
                          ${PROJECT_SOURCE_DIR}/weights/*.md)
install(FILES ${HF_WEIGHT_FILES} ${PROJECT_SOURCE_DIR}/weights/hfnet.py
              ${PROJECT_SOURCE_DIR}/weights/safetensors_header.py
        DESTINATION ${CMAKE_INSTALL_DATADIR}/hairfilter/weights)
install(FILES ${PROJECT_SOURCE_DIR}/bench/bench_torch.py
        DESTINATION ${CMAKE_INSTALL_DATADIR}/hairfilter/bench)
install(FILES LICENSE CHANGELOG.md README.md cmake/debian/copyright
              protocol/PROTOCOL.md protocol/FEATURES.md
        DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(FILES client/lib/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR} RENAME CLIENT.md)

if(NOT HF_CLIENT_ONLY)
  # The service unit and the example config file of deploy/systemd, their
  # /usr/local paths replaced with the prefix's at install time (--prefix and
  # cpack's /usr included). The config goes beside the weights; the DEB's
  # postinst copies it to /etc/hairfilter, where the unit reads it, when no
  # config is there yet (an operator's file is never overwritten).
  set(HF_DEPLOY_TMP ${PROJECT_BINARY_DIR}/install-unit)
  install(CODE "
    set(bindir \"${CMAKE_INSTALL_BINDIR}\")
    set(datadir \"${CMAKE_INSTALL_DATAROOTDIR}\")
    if(NOT IS_ABSOLUTE \"\${bindir}\")
      set(bindir \"\${CMAKE_INSTALL_PREFIX}/\${bindir}\")
    endif()
    if(NOT IS_ABSOLUTE \"\${datadir}\")
      set(datadir \"\${CMAKE_INSTALL_PREFIX}/\${datadir}\")
    endif()
    foreach(f hairfilterd.service hairfilterd.conf)
      file(READ \"${PROJECT_SOURCE_DIR}/deploy/systemd/\${f}\" text)
      string(REPLACE \"/usr/local/bin/\" \"\${bindir}/\" text \"\${text}\")
      string(REPLACE \"/usr/local/share/\" \"\${datadir}/\" text \"\${text}\")
      file(WRITE \"${HF_DEPLOY_TMP}/\${f}\" \"\${text}\")
    endforeach()
    file(INSTALL DESTINATION \"\${CMAKE_INSTALL_PREFIX}/lib/systemd/system\"
         TYPE FILE PERMISSIONS OWNER_READ OWNER_WRITE GROUP_READ WORLD_READ
         FILES \"${HF_DEPLOY_TMP}/hairfilterd.service\")
    file(INSTALL DESTINATION \"\${datadir}/hairfilter\"
         TYPE FILE PERMISSIONS OWNER_READ OWNER_WRITE GROUP_READ WORLD_READ
         FILES \"${HF_DEPLOY_TMP}/hairfilterd.conf\")")
  # The unit's Documentation= page.
  install(FILES docs/SERVER.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
endif()

# ---- the DEB --------------------------------------------------------------
# cpack -G DEB in the build folder makes hairfilter_<version>_<arch>.deb with
# everything above under /usr, its library dependencies found by
# dpkg-shlibdeps (a build with the cudnn backend needs cuDNN 9 where it is
# installed; configure with -DHF_WITH_CUDNN=OFF for a CPU-only package, and
# -DHF_RENDERER=OFF to leave out OSMesa). The maintainer scripts create the
# hairfilter system user and group the service runs as (docs/SERVER.md).
set(CPACK_PACKAGE_NAME hairfilter)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_CONTACT "hairfilter maintainers <hairfilter@localhost>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY
    "real-time hair filtering service (hairfilterd), client library and tools")
set(CPACK_PACKAGE_DESCRIPTION
    "hairfilterd filters stochastic-transparency hair renders with a small U-Net\n\
on the GPU (cuDNN) or the CPU, as a service over Unix sockets, TCP and\n\
shared memory. The package holds the daemon and its systemd unit, the bundled\n\
network weights, the hairfilter command line, hairfilter-load, the C and C++\n\
client library (libhairfilter) with its CMake and pkg-config files, and the\n\
Python client.")
if(HF_HAVE_CUDNN)
  # cuDNN comes from NVIDIA, not Debian: dpkg-shlibdeps cannot name its
  # package, so the description says what the cudnn backend needs.
  string(APPEND CPACK_PACKAGE_DESCRIPTION "\n\
This build has the cudnn backend: hairfilterd needs cuDNN 9 (libcudnn.so.9)\n\
on the library path and an NVIDIA driver; a CPU-only package is built with\n\
-DHF_WITH_CUDNN=OFF.")
endif()
set(CPACK_RESOURCE_FILE_LICENSE ${PROJECT_SOURCE_DIR}/LICENSE)
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION graphics)
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_GENERATE_SHLIBS ON)
set(CPACK_DEBIAN_PACKAGE_DEPENDS "passwd")
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "python3, python3-numpy")
# libssl3 (TLS) comes in through dpkg-shlibdeps; an engine that links the
# static libhairfilter.a needs OpenSSL's development files too.
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "libssl-dev")
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA ${PROJECT_SOURCE_DIR}/cmake/debian/postinst
    ${PROJECT_SOURCE_DIR}/cmake/debian/prerm ${PROJECT_SOURCE_DIR}/cmake/debian/postrm
    ${PROJECT_SOURCE_DIR}/cmake/debian/triggers)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION TRUE)
set(CPACK_GENERATOR DEB)
include(CPack)
