// fmt's compiled part, built once here instead of in every translation unit (FMT_HEADER_ONLY
// put it in each: about 3.5 s of compile time per file) and instead of linking libfmt.so (the
// SDK's library must keep every allocation behind its allocator hook, so fmt's code has to live
// inside it). Every target gets fmt through pstream_base; nothing defines FMT_HEADER_ONLY.
//
// format-inl.h defines fmt's non-template functions; the templates that format.h declares
// `extern` are instantiated here for the character types fmt supports.
#include <fmt/format-inl.h>

#include <locale>

FMT_BEGIN_NAMESPACE
namespace detail {

template FMT_API locale_ref::locale_ref(const std::locale& loc);
template FMT_API auto locale_ref::get<std::locale>() const -> std::locale;

template FMT_API auto thousands_sep_impl<char>(locale_ref) -> thousands_sep_result<char>;
template FMT_API auto thousands_sep_impl<wchar_t>(locale_ref) -> thousands_sep_result<wchar_t>;
template FMT_API auto decimal_point_impl(locale_ref) -> char;
template FMT_API auto decimal_point_impl(locale_ref) -> wchar_t;

}  // namespace detail
FMT_END_NAMESPACE
