//! Derives for nerfsv's config types.
//!
//! `#[derive(ValidateTables)]` checks each `#[docs(table)]` field of a config with its own
//! `validate`, its errors named `table.key` (see [`macro@ValidateTables`]).
//!
//! `#[derive(Defaults)]` writes a config's `Default` from its fields: each field's value is its
//! `#[docs(default = EXPR)]` or its type's own default (see [`macro@Defaults`]).
//!
//! `#[derive(FieldDocs)]`: a struct's named fields with their doc comments, as data. For a struct with named fields it generates an inherent constant
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
use syn::{parse_macro_input, Attribute, Data, DeriveInput, Expr, Fields, Lit, LitStr, Meta};

/// A field marked `#[docs(table)]` is a sub-table whose type derives `FieldDocs` too: the
/// generated `TableDocs::tables` then lists it (and its own sub-tables) after the struct itself,
/// so that the whole config's tables come from the top-level struct alone.
#[proc_macro_derive(FieldDocs, attributes(docs))]
pub fn field_docs(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    let name = &input.ident;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    let fields = match named_fields(&input, "FieldDocs") {
        Ok(f) => f,
        Err(e) => return e.to_compile_error().into(),
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
    let tables = fields.named.iter().filter(|f| is_table(&f.attrs)).map(|f| {
        let field = f.ident.as_ref().map(|i| i.to_string()).unwrap_or_default();
        let ty = option_inner(&f.ty).unwrap_or(&f.ty);
        quote! {
            <#ty>::tables(&if prefix.is_empty() { #field.to_owned() } else { format!("{prefix}.{}", #field) }, out);
        }
    });
    let struct_name = name.to_string();
    quote! {
        impl #impl_generics #name #ty_generics #where_clause {
            /// Each field's name and documentation, in declaration order (`#[derive(FieldDocs)]`).
            pub const FIELD_DOCS: &'static [(&'static str, &'static str)] = &[#(#entries),*];

            /// This struct's table at `prefix` (`""` for the top level), then its sub-tables (the
            /// fields marked `#[docs(table)]`), depth first: `(path, struct name, FIELD_DOCS)`.
            pub fn tables(
                prefix: &str,
                out: &mut Vec<(String, &'static str, &'static [(&'static str, &'static str)])>,
            ) {
                out.push((prefix.to_owned(), #struct_name, Self::FIELD_DOCS));
                #(#tables)*
            }
        }
    }
    .into()
}

/// `#[derive(ValidateTables)]`: every sub-table of a config checked by its own `validate`.
///
/// It generates `validate_tables(&self)`, which calls `validate()` (an inherent method or a
/// trait's in scope) on each field marked `#[docs(table)]` (an `Option<T>` table when it is
/// set), in declaration order, and returns the first error named within the field's table
/// (`e.within("field")`: `uq_offline.ga_images_per_split`). The error type is
/// `nerfsv_scene::InvalidValue` unless the struct says `#[docs(error = "Path")]`; it needs a
/// `within(self, &str) -> Self`. Checks that join tables stay hand-written beside the call.
///
/// ```ignore
/// #[derive(nerfsv_derive::FieldDocs, nerfsv_derive::ValidateTables)]
/// pub struct Run {
///     /// The camera.
///     #[docs(table)]
///     pub camera: Camera,
/// }
/// // Camera::validate refuses width 0 as "width": the run names it "camera.width".
/// assert_eq!(run.validate_tables().unwrap_err().field, "camera.width");
/// ```
#[proc_macro_derive(ValidateTables, attributes(docs))]
pub fn validate_tables(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    let name = &input.ident;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    let fields = match named_fields(&input, "ValidateTables") {
        Ok(f) => f,
        Err(e) => return e.to_compile_error().into(),
    };
    let error: syn::Path = match string_attr(&input.attrs, "docs", "error") {
        Some(path) => match syn::parse_str(&path) {
            Ok(p) => p,
            Err(e) => return e.to_compile_error().into(),
        },
        None => syn::parse_quote!(::nerfsv_scene::InvalidValue),
    };
    let checks = fields.named.iter().filter(|f| is_table(&f.attrs)).map(|f| {
        let ident = f.ident.as_ref().expect("named field");
        let table = ident.to_string();
        // A table's `#[cfg(…)]` holds for its check too.
        let cfgs = f.attrs.iter().filter(|a| a.path().is_ident("cfg"));
        match option_inner(&f.ty) {
            Some(_) => quote! {
                #(#cfgs)*
                if let Some(t) = &self.#ident {
                    t.validate().map_err(|e| e.within(#table))?;
                }
            },
            None => quote! {
                #(#cfgs)*
                self.#ident.validate().map_err(|e| e.within(#table))?;
            },
        }
    });
    quote! {
        impl #impl_generics #name #ty_generics #where_clause {
            /// Checks every `#[docs(table)]` field with its own `validate`, in declaration order;
            /// the first error names its key within the table (`table.key`)
            /// (`#[derive(ValidateTables)]`).
            pub fn validate_tables(&self) -> Result<(), #error> {
                #(#checks)*
                Ok(())
            }
        }
    }
    .into()
}

/// `#[derive(Defaults)]`: `impl Default` from the fields, each field's default beside its
/// declaration.
///
/// A field marked `#[docs(default = EXPR)]` starts as `EXPR`; every other field as its type's
/// `Default::default()`. So a table added to a config is its field alone: its type's default is
/// the config's. A field's `#[cfg(…)]` holds for its value too.
///
/// ```ignore
/// #[derive(nerfsv_derive::Defaults)]
/// pub struct Run {
///     /// Scene name.
///     #[docs(default = "stonehenge".into())]
///     pub scene: String,
///     /// The camera (its own default).
///     pub camera: Camera,
/// }
/// assert_eq!(Run::default().scene, "stonehenge");
/// ```
#[proc_macro_derive(Defaults, attributes(docs))]
pub fn defaults(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    let name = &input.ident;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    let fields = match named_fields(&input, "Defaults") {
        Ok(f) => f,
        Err(e) => return e.to_compile_error().into(),
    };
    let mut values = Vec::new();
    for f in &fields.named {
        let ident = f.ident.as_ref().expect("named field");
        let cfgs = f.attrs.iter().filter(|a| a.path().is_ident("cfg"));
        let value = match default_attr(&f.attrs) {
            Ok(Some(expr)) => quote! { #expr },
            Ok(None) => quote! { ::std::default::Default::default() },
            Err(e) => return e.to_compile_error().into(),
        };
        values.push(quote! { #(#cfgs)* #ident: #value, });
    }
    quote! {
        impl #impl_generics ::std::default::Default for #name #ty_generics #where_clause {
            /// Each field's `#[docs(default = …)]`, else its type's default (`#[derive(Defaults)]`).
            fn default() -> Self {
                Self { #(#values)* }
            }
        }
    }
    .into()
}

/// The expression of a field's `#[docs(default = EXPR)]`, if it has one.
fn default_attr(attrs: &[Attribute]) -> syn::Result<Option<Expr>> {
    let mut found = None;
    for a in attrs.iter().filter(|a| a.path().is_ident("docs")) {
        a.parse_nested_meta(|m| {
            if m.path.is_ident("default") {
                found = Some(m.value()?.parse::<Expr>()?);
            } else if m.input.peek(syn::Token![=]) {
                m.value()?.parse::<Expr>()?;
            }
            Ok(())
        })?;
    }
    Ok(found)
}

/// `#[derive(Choice)]`: a fieldless enum chosen by name in config files, on the command line and
/// from Python.
///
/// It generates `ALL` (every variant, in declaration order), `name()` (the variant's
/// `#[serde(rename = "…")]` if it has one, else its identifier in kebab case: `Ga` → `"ga"`,
/// `CemIs` → `"cem-is"`), `Display` (the name) and `FromStr`, whose error lists the names and
/// calls the value by `#[choice(what = "…")]` or by the type's name in words (`UqMode` →
/// "uq mode").
///
/// ```ignore
/// #[derive(nerfsv_derive::Choice, Clone, Copy)]
/// pub enum Method { Ga, Bla }
/// assert_eq!("bla".parse::<Method>().unwrap().name(), "bla");
/// assert_eq!("x".parse::<Method>().unwrap_err(), "unknown method \"x\": one of ga, bla");
/// ```
#[proc_macro_derive(Choice, attributes(choice))]
pub fn choice(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    let name = &input.ident;
    let Data::Enum(data) = &input.data else {
        return syn::Error::new_spanned(name, "Choice is for enums").to_compile_error().into();
    };
    let mut variants = Vec::new();
    let mut names = Vec::new();
    for v in &data.variants {
        if !matches!(v.fields, Fields::Unit) {
            return syn::Error::new_spanned(v, "Choice needs fieldless variants").to_compile_error().into();
        }
        variants.push(&v.ident);
        names.push(string_attr(&v.attrs, "serde", "rename").unwrap_or_else(|| words(&v.ident.to_string(), "-")));
    }
    let what = string_attr(&input.attrs, "choice", "what").unwrap_or_else(|| words(&name.to_string(), " "));
    let count = variants.len();
    quote! {
        impl #name {
            /// Every variant, in declaration order (`#[derive(Choice)]`).
            pub const ALL: [#name; #count] = [#(#name::#variants),*];

            /// The name config files, flags and Python use (`#[derive(Choice)]`).
            pub fn name(self) -> &'static str {
                match self {
                    #(#name::#variants => #names,)*
                }
            }
        }

        impl ::std::fmt::Display for #name {
            fn fmt(&self, f: &mut ::std::fmt::Formatter<'_>) -> ::std::fmt::Result {
                f.write_str(self.name())
            }
        }

        impl ::std::str::FromStr for #name {
            type Err = String;

            fn from_str(s: &str) -> Result<Self, String> {
                #name::ALL.into_iter().find(|v| v.name() == s).ok_or_else(|| {
                    let names: Vec<&str> = #name::ALL.iter().map(|v| v.name()).collect();
                    format!("unknown {} {s:?}: one of {}", #what, names.join(", "))
                })
            }
        }
    }
    .into()
}

/// The named fields of the struct `input`, or the error `derive` gives for anything else.
fn named_fields<'a>(input: &'a DeriveInput, derive: &str) -> syn::Result<&'a syn::FieldsNamed> {
    match &input.data {
        Data::Struct(data) => match &data.fields {
            Fields::Named(fields) => Ok(fields),
            _ => Err(syn::Error::new_spanned(&input.ident, format!("{derive} needs named fields"))),
        },
        _ => Err(syn::Error::new_spanned(&input.ident, format!("{derive} is for structs"))),
    }
}

/// `T` of a field typed `Option<T>` (a table that is unset by default).
fn option_inner(ty: &syn::Type) -> Option<&syn::Type> {
    let syn::Type::Path(p) = ty else { return None };
    let last = p.path.segments.last()?;
    let syn::PathArguments::AngleBracketed(args) = &last.arguments else { return None };
    match (last.ident == "Option", args.args.first()) {
        (true, Some(syn::GenericArgument::Type(inner))) => Some(inner),
        _ => None,
    }
}

/// Whether the field says `#[docs(table)]`.
fn is_table(attrs: &[Attribute]) -> bool {
    let mut table = false;
    for a in attrs.iter().filter(|a| a.path().is_ident("docs")) {
        let _ = a.parse_nested_meta(|m| {
            table |= m.path.is_ident("table");
            if m.input.peek(syn::Token![=]) {
                m.value()?.parse::<Expr>()?;
            }
            Ok(())
        });
    }
    table
}

/// `key`'s string in an attribute `#[outer(key = "…")]`, if one says it.
fn string_attr(attrs: &[Attribute], outer: &str, key: &str) -> Option<String> {
    let mut found = None;
    for a in attrs.iter().filter(|a| a.path().is_ident(outer)) {
        let _ = a.parse_nested_meta(|m| {
            if m.path.is_ident(key) {
                found = Some(m.value()?.parse::<LitStr>()?.value());
            } else if m.input.peek(syn::Token![=]) {
                m.value()?.parse::<Expr>()?;
            }
            Ok(())
        });
    }
    found
}

/// `CemIs` as `"cem-is"` (with `sep` "-") or `"cem is"`.
fn words(ident: &str, sep: &str) -> String {
    let mut out = String::new();
    for (i, c) in ident.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push_str(sep);
        }
        out.extend(c.to_lowercase());
    }
    out
}
