# Included into the interface packages' CMake projects by scripts/build_interfaces.sh
# (CMAKE_PROJECT_INCLUDE; CMake >= 3.19) when they are built against the ROS 2 Jazzy PyPI wheels, never on a
# ROS install: those wheels' exported targets name the wheel builder's include directories
# (/opt/python/...), which do not exist here and fail CMake's generate step. At the end of the
# configure step, such paths are dropped from every imported target.
function(densecalib_drop_missing_include_dirs)
  get_property(imported DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(target IN LISTS imported)
    get_target_property(dirs ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(dirs)
      set(existing "")
      foreach(dir IN LISTS dirs)
        if(EXISTS "${dir}" OR dir MATCHES "^\\$<")
          list(APPEND existing "${dir}")
        endif()
      endforeach()
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${existing}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL densecalib_drop_missing_include_dirs)
