# The public headers compile without a warning under the strict flags an
# engine may build with (-Werror): hairfilter.h as C99 and C11 (and as
# C++), hairfilter.hpp as C++11, 17 and 20, with and without exceptions.
# A header's warning is the engine's build error. Run by ctest:
#   cmake -DCC=... -DCXX=... -DINCLUDES="a|b" -DWORK=... -P header_warnings.cmake
file(MAKE_DIRECTORY ${WORK})
set(inc "")
string(REPLACE "|" ";" INCLUDES "${INCLUDES}")
foreach(d IN LISTS INCLUDES)
  list(APPEND inc -I${d})
endforeach()
file(WRITE ${WORK}/h.c "#include <hairfilter/hairfilter.h>
int use_header(void);
int use_header(void) {
  hfc_options o;
  hfc_request r;
  hfc_options_init(&o);
  hfc_request_init(&r);
  return o.struct_size == r.struct_size;
}
")
file(WRITE ${WORK}/h.cpp "#include <hairfilter/hairfilter.hpp>
int use_header();
int use_header() {
  hairfilter::Options o;
  hairfilter::Request r;
  hairfilter::Client c;
  hairfilter::SharedBuffer b;
  hairfilter::Status s;
  return c.pending() + static_cast<int>(b.size()) + s.code + static_cast<int>(r.struct_size) +
         static_cast<int>(o.struct_size);
}
")
set(common -Wall -Wextra -Werror -pedantic -Wshadow -Wconversion -Wsign-conversion -Wcast-qual
           -Wcast-align -Wundef -Wmissing-declarations)
set(c_warn ${common} -Wstrict-prototypes -Wmissing-prototypes -Wold-style-definition)
set(cpp_warn ${common} -Weffc++ -Wold-style-cast -Wzero-as-null-pointer-constant -Wuseless-cast
             -Wnon-virtual-dtor -Woverloaded-virtual)
function(compile name compiler src)
  execute_process(COMMAND ${compiler} ${ARGN} ${inc} -c ${src} -o ${WORK}/${name}.o
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
  if(rc)
    message(FATAL_ERROR "header_warnings: ${name} (${ARGN}) does not compile cleanly:\n${out}")
  endif()
  message(STATUS "header_warnings: ${name} compiles cleanly")
endfunction()
compile(c99 ${CC} ${WORK}/h.c -std=c99 ${c_warn})
compile(c11 ${CC} ${WORK}/h.c -std=c11 ${c_warn})
compile(h_as_cpp11 ${CXX} ${WORK}/h.c -x c++ -std=c++11 ${cpp_warn})
compile(cpp11 ${CXX} ${WORK}/h.cpp -std=c++11 ${cpp_warn})
compile(cpp17 ${CXX} ${WORK}/h.cpp -std=c++17 ${cpp_warn})
compile(cpp20 ${CXX} ${WORK}/h.cpp -std=c++20 ${cpp_warn})
compile(cpp11_noexcept ${CXX} ${WORK}/h.cpp -std=c++11 -fno-exceptions ${cpp_warn})
