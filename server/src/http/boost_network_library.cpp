// Asio's and Beast's own (non-template) functions, compiled once here rather than inline in every
// front-end translation unit (BOOST_ASIO_SEPARATE_COMPILATION and BOOST_BEAST_SEPARATE_COMPILATION,
// set on tendril_http for everything that links it). Each TU that included Boost.Asio compiled and
// optimised the scheduler, reactor, TLS engine, SHA-1, zlib and the HTTP parser again; here they are
// built once, which shortens the release build that scripts/run.sh waits for.
#include <boost/asio/impl/src.hpp>
#include <boost/asio/ssl/impl/src.hpp>
#include <boost/beast/src.hpp>
