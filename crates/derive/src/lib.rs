//! `#[derive(FieldDocs)]`: a struct's named fields with their doc comments, as data.
//!
//! For a struct with named fields it generates an inherent constant
//! `FIELD_DOCS: &[(&str, &str)]`: each field's name and its documentation, the doc comment's
//! lines trimmed and joined by one space, intra-doc link brackets (`` [`x`] ``) dropped, in
//! declaration order. `nerfsv config --default` writes the default config with these as
//! comments, so the file documents every key from the code's own docs.
//!
//! ```ignore
//! #[derive(nerfsv_derive::FieldDocs)]
//! pub struct Camera {
//!     /// Image width, pixels.
//!     pub width: u32,
//! }
//! assert_eq!(Camera::FIELD_DOCS, &[("width", "Image width, pixels.")]);
//! ```

use proc_macro::TokenStream;
use quote::quote;
use syn::{parse_macro_input, Data, DeriveInput, Expr, Fields, Lit, Meta};

#[proc_macro_derive(FieldDocs)]
pub fn field_docs(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    let name = &input.ident;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    let Data::Struct(data) = &input.data else {
        return syn::Error::new_spanned(&input.ident, "FieldDocs is for structs").to_compile_error().into();
    };
    let Fields::Named(fields) = &data.fields else {
        return syn::Error::new_spanned(&input.ident, "FieldDocs needs named fields").to_compile_error().into();
    };
    let entries = fields.named.iter().map(|f| {
        let field = f.ident.as_ref().map(|i| i.to_string()).unwrap_or_default();
        let lines: Vec<String> = f
            .attrs
            .iter()
            .filter_map(|a| match &a.meta {
                Meta::NameValue(nv) if nv.path.is_ident("doc") => match &nv.value {
                    Expr::Lit(e) => match &e.lit {
                        Lit::Str(s) => Some(s.value().trim().to_owned()),
                        _ => None,
                    },
                    _ => None,
                },
                _ => None,
            })
            .collect();
        let doc = lines.join(" ").replace("[`", "`").replace("`]", "`").trim().to_owned();
        quote! { (#field, #doc) }
    });
    quote! {
        impl #impl_generics #name #ty_generics #where_clause {
            /// Each field's name and documentation, in declaration order (`#[derive(FieldDocs)]`).
            pub const FIELD_DOCS: &'static [(&'static str, &'static str)] = &[#(#entries),*];
        }
    }
    .into()
}
