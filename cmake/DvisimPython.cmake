# The Python module's dependencies (python/CMakeLists.txt, docs/PYTHON.md): pybind11 (Debian: pybind11-dev), the
# interpreter's headers (python3-dev) and an interpreter that imports numpy (python3-numpy). DVISIM_BUILD_PYTHON is
# on where all are found, off with a message where not.
#
# The interpreter: DVISIM_PYTHON_EXECUTABLE when given, else the first of Python3_EXECUTABLE (when given),
# /usr/bin/python3 and the python3 on PATH that imports numpy. /usr/bin/python3 comes before PATH's so that a
# pyenv or conda python3 without numpy does not hide Debian's, whose numpy and pytest the tests need.
if(NOT DVISIM_PYTHON_EXECUTABLE)
  find_program(_dvisim_path_python3 python3)
  set(_dvisim_py_candidates ${Python3_EXECUTABLE} /usr/bin/python3 ${_dvisim_path_python3})
  foreach(_py ${_dvisim_py_candidates})
    if(EXISTS "${_py}")
      execute_process(COMMAND ${_py} -c "import numpy" RESULT_VARIABLE _rc OUTPUT_QUIET ERROR_QUIET)
      if(_rc EQUAL 0)
        set(DVISIM_PYTHON_EXECUTABLE ${_py} CACHE FILEPATH "The Python interpreter of the dvisim module and its tests")
        break()
      endif()
    endif()
  endforeach()
endif()

set(_dvisim_py_missing "")
if(NOT DVISIM_PYTHON_EXECUTABLE)
  set(_dvisim_py_missing "no python3 that imports numpy (Debian: python3-numpy)")
else()
  set(Python3_EXECUTABLE ${DVISIM_PYTHON_EXECUTABLE})
  find_package(Python3 COMPONENTS Interpreter Development.Module QUIET)
  if(NOT Python3_Development.Module_FOUND)
    set(_dvisim_py_missing "no Python headers for ${DVISIM_PYTHON_EXECUTABLE} (Debian: python3-dev)")
  else()
    find_package(pybind11 CONFIG QUIET)
    if(NOT pybind11_FOUND)
      set(_dvisim_py_missing "pybind11 not found (Debian: pybind11-dev)")
    endif()
  endif()
endif()

if(_dvisim_py_missing STREQUAL "")
  option(DVISIM_BUILD_PYTHON "Build the Python module dvisim" ON)
else()
  option(DVISIM_BUILD_PYTHON "Build the Python module dvisim" OFF)
  if(DVISIM_BUILD_PYTHON)
    message(FATAL_ERROR "dvisim: DVISIM_BUILD_PYTHON is on but ${_dvisim_py_missing}")
  endif()
endif()
if(DVISIM_BUILD_PYTHON)
  message(STATUS "dvisim: Python module enabled (${DVISIM_PYTHON_EXECUTABLE}, Python ${Python3_VERSION}, "
                 "pybind11 ${pybind11_VERSION})")
else()
  message(STATUS "dvisim: building without the Python module: ${_dvisim_py_missing}")
endif()
