# deepcanvas_find_openvdb(): OpenVDB::openvdb, without the Boost.Iostreams that Debian's
# FindOpenVDB.cmake adds to its interface.
#
# Why: Debian 12's libopenvdb.so is built against Boost 1.74 and links libboost_iostreams 1.74
# itself, while FindOpenVDB finds Boost.Iostreams by whatever config is installed (1.81 here,
# setup.sh installs Boost 1.81 for Beast). Linked as well, the 1.81 library is loaded ahead of
# OpenVDB's own and its symbols would take the calls OpenVDB compiled against 1.74 (the linker
# warns "may conflict"). deepcanvas never calls Boost.Iostreams; OpenVDB keeps its own.
macro(deepcanvas_find_openvdb)
  list(APPEND CMAKE_MODULE_PATH /usr/lib/x86_64-linux-gnu/cmake/OpenVDB /usr/lib/cmake/OpenVDB)
  find_package(OpenVDB REQUIRED)
  get_target_property(_deepcanvas_vdb_libs OpenVDB::openvdb INTERFACE_LINK_LIBRARIES)
  if(_deepcanvas_vdb_libs)
    list(REMOVE_ITEM _deepcanvas_vdb_libs Boost::iostreams)
    set_target_properties(OpenVDB::openvdb PROPERTIES INTERFACE_LINK_LIBRARIES "${_deepcanvas_vdb_libs}")
  endif()
endmacro()
