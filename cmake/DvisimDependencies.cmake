# Finds dvisim's dependencies and defines imported targets for the ones without a usable CMake target.
# Used by the build and by the installed dvisimConfig.cmake alike.
include(CMakeFindDependencyMacro)
find_package(OpenMP REQUIRED COMPONENTS CXX)
find_package(nlohmann_json 3 REQUIRED)
find_package(Eigen3 REQUIRED NO_MODULE)

# Debian's BulletConfig.cmake hard-codes /usr; find headers and libraries through the prefix path
# instead, so a relocated copy (the GPU machine's unpacked .deps) works too.
if(NOT TARGET dvisim::bullet)
  find_path(DVISIM_BULLET_INCLUDE_DIR btBulletDynamicsCommon.h PATH_SUFFIXES bullet REQUIRED)
  set(_dvisim_bullet_libs "")
  foreach(_lib BulletWorldImporter BulletFileLoader BulletDynamics BulletCollision LinearMath)
    find_library(DVISIM_${_lib}_LIBRARY NAMES ${_lib} REQUIRED)
    list(APPEND _dvisim_bullet_libs ${DVISIM_${_lib}_LIBRARY})
  endforeach()
  add_library(dvisim::bullet INTERFACE IMPORTED)
  set_target_properties(dvisim::bullet PROPERTIES
    INTERFACE_INCLUDE_DIRECTORIES "${DVISIM_BULLET_INCLUDE_DIR};${DVISIM_BULLET_INCLUDE_DIR}/BulletWorldImporter"
    INTERFACE_LINK_LIBRARIES "${_dvisim_bullet_libs}")
endif()
