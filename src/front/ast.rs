//! The syntax tree of a substance file, as written, with spans. The type checker turns node
//! bodies into [`crate::front::hir`] and the graph resolver turns graph declarations into
//! [`crate::front::graph`] values; nothing downstream reads the AST.

use crate::diag::Span;

/// A name with its location.
#[derive(Clone, Debug, PartialEq)]
pub struct Ident {
    /// The name as written.
    pub name: String,
    /// Where it is written.
    pub span: Span,
}

/// The scalar or triple type named in source, before array dimensions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BaseType {
    /// `float`
    Float,
    /// `int`
    Int,
    /// `color`
    Color,
    /// `point`
    Point,
    /// `vector`
    Vector,
    /// `normal`
    Normal,
    /// `string`
    String,
    /// `closure`
    Closure,
    /// `void` (function results only)
    Void,
}

/// A type as written: base type and an optional fixed array length.
#[derive(Clone, Debug, PartialEq)]
pub struct TypeExpr {
    /// The element type.
    pub base: BaseType,
    /// `Some(n)` for `T name[n]`.
    pub array: Option<u32>,
    /// Where the type is written.
    pub span: Span,
}

/// A whole `.ash` file.
#[derive(Clone, Debug, Default)]
pub struct Module {
    /// Top-level declarations in source order.
    pub items: Vec<Item>,
}

/// A top-level declaration.
#[derive(Clone, Debug)]
pub enum Item {
    /// `import "other.ash";`
    Import {
        /// The path as written (relative to the importing file).
        path: String,
        /// Where the path string is written.
        span: Span,
    },
    /// A `shader` (node type) or a plain function.
    Function(FunctionDecl),
    /// A `substance` or `override` graph.
    Graph(GraphDecl),
}

/// Whether a function is a node type or a helper function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FunctionKind {
    /// `shader name(...) { ... }`: a node type usable in graphs.
    Shader,
    /// `type name(...) { ... }`: a helper callable from bodies.
    Function,
}

/// A parameter of a shader or function.
#[derive(Clone, Debug)]
pub struct Param {
    /// Declared with `output`.
    pub output: bool,
    /// Its type.
    pub ty: TypeExpr,
    /// Its name.
    pub name: Ident,
    /// Default value (shaders: every parameter has one, implicit zero otherwise).
    pub default: Option<Expr>,
}

/// A shader or function definition.
#[derive(Clone, Debug)]
pub struct FunctionDecl {
    /// Shader or function.
    pub kind: FunctionKind,
    /// Result type (`void` for shaders).
    pub ret: TypeExpr,
    /// The name.
    pub name: Ident,
    /// Parameters in order.
    pub params: Vec<Param>,
    /// The body.
    pub body: Block,
    /// The whole declaration.
    pub span: Span,
}

/// `{ statements }`
#[derive(Clone, Debug, Default)]
pub struct Block {
    /// Statements in order.
    pub stmts: Vec<Stmt>,
    /// The parser gave up inside this block (it nests past
    /// [`MAX_NESTING`](crate::front::parser::MAX_NESTING), already reported) and skipped the
    /// rest: checks that need the whole body, such as "every path returns", do not apply.
    pub skipped: bool,
}

/// Assignment operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AssignOp {
    /// `=`
    Set,
    /// `+=`
    Add,
    /// `-=`
    Sub,
    /// `*=`
    Mul,
    /// `/=`
    Div,
}

/// A statement.
#[derive(Clone, Debug)]
pub struct Stmt {
    /// What it does.
    pub kind: StmtKind,
    /// Where.
    pub span: Span,
}

/// The statement forms.
#[derive(Clone, Debug)]
pub enum StmtKind {
    /// `type name [= init];` or `type name[n] [= {…}];`
    Local {
        /// Declared type.
        ty: TypeExpr,
        /// Name.
        name: Ident,
        /// Initialiser.
        init: Option<Expr>,
    },
    /// `target op value;` (also `x++` / `x--` as `x += 1` / `x -= 1`)
    Assign {
        /// A variable, component or element.
        target: Expr,
        /// The operator.
        op: AssignOp,
        /// The right-hand side.
        value: Expr,
    },
    /// An expression evaluated for its effect (a call).
    Expr(Expr),
    /// `if (cond) then [else otherwise]`
    If {
        /// Condition.
        cond: Expr,
        /// Taken branch.
        then: Block,
        /// Other branch.
        otherwise: Option<Block>,
    },
    /// `for (init; cond; step) body`
    For {
        /// Runs once first.
        init: Option<Box<Stmt>>,
        /// Checked before each iteration (absent: always true).
        cond: Option<Expr>,
        /// Runs after each iteration.
        step: Option<Box<Stmt>>,
        /// The loop body.
        body: Block,
    },
    /// `while (cond) body`
    While {
        /// Checked before each iteration.
        cond: Expr,
        /// The loop body.
        body: Block,
    },
    /// `break;`
    Break,
    /// `continue;`
    Continue,
    /// `return [value];`
    Return(Option<Expr>),
    /// A nested `{ … }` scope.
    Block(Block),
}

/// Unary operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnaryOp {
    /// `-x`
    Neg,
    /// `!x`
    Not,
}

/// Binary operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinaryOp {
    /// `+`
    Add,
    /// `-`
    Sub,
    /// `*`
    Mul,
    /// `/`
    Div,
    /// `%`
    Rem,
    /// `==`
    Eq,
    /// `!=`
    Ne,
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
    /// `&&`
    And,
    /// `||`
    Or,
}

impl BinaryOp {
    /// The operator as written.
    pub fn symbol(self) -> &'static str {
        use BinaryOp::*;
        match self {
            Add => "+",
            Sub => "-",
            Mul => "*",
            Div => "/",
            Rem => "%",
            Eq => "==",
            Ne => "!=",
            Lt => "<",
            Le => "<=",
            Gt => ">",
            Ge => ">=",
            And => "&&",
            Or => "||",
        }
    }
}

/// An expression.
#[derive(Clone, Debug)]
pub struct Expr {
    /// What it computes.
    pub kind: ExprKind,
    /// Where.
    pub span: Span,
}

impl Drop for Expr {
    /// Drops the tree without recursing per level: a flat chain of 100 000 `+` is a left-deep
    /// tree 100 000 levels deep, and the derived drop would recurse once per level.
    fn drop(&mut self) {
        let mut pending = Vec::new();
        self.kind.take_subtrees(&mut pending);
        while let Some(mut expr) = pending.pop() {
            expr.kind.take_subtrees(&mut pending);
        }
    }
}

impl ExprKind {
    /// Moves every operand that has operands of its own into `out`, leaving a leaf behind, so
    /// that dropping `self` afterwards does not recurse.
    fn take_subtrees(&mut self, out: &mut Vec<Expr>) {
        let mut take = |slot: &mut Expr| {
            if slot.kind.has_operands() {
                out.push(std::mem::replace(slot, Expr { kind: ExprKind::Error, span: slot.span }));
            }
        };
        match self {
            ExprKind::Unary(_, a) | ExprKind::Member(a, _) => take(a),
            ExprKind::Binary(_, a, b) | ExprKind::Index(a, b) => {
                take(a);
                take(b);
            }
            ExprKind::Ternary(a, b, c) => {
                take(a);
                take(b);
                take(c);
            }
            ExprKind::Call(_, items) | ExprKind::List(items) => items.iter_mut().for_each(take),
            ExprKind::Float(_) | ExprKind::Int(_) | ExprKind::Str(_) | ExprKind::Name(_) | ExprKind::Error => {}
        }
    }

    fn has_operands(&self) -> bool {
        !matches!(self, ExprKind::Float(_) | ExprKind::Int(_) | ExprKind::Str(_) | ExprKind::Name(_) | ExprKind::Error)
    }
}

/// The expression forms.
#[derive(Clone, Debug)]
pub enum ExprKind {
    /// `1.5`
    Float(f64),
    /// `3`
    Int(i64),
    /// `"text"` (escapes resolved)
    Str(String),
    /// A variable, global or graph reference.
    Name(String),
    /// `op x`
    Unary(UnaryOp, Box<Expr>),
    /// `a op b`
    Binary(BinaryOp, Box<Expr>, Box<Expr>),
    /// `c ? a : b`
    Ternary(Box<Expr>, Box<Expr>, Box<Expr>),
    /// `f(args)`, including type constructors such as `color(1, 0, 0)`.
    Call(Ident, Vec<Expr>),
    /// `base.name`: a component (`p.x`, `c.r`) or, in graphs, a node output.
    Member(Box<Expr>, Ident),
    /// `base[index]`
    Index(Box<Expr>, Box<Expr>),
    /// `{a, b, c}` (array initialisers)
    List(Vec<Expr>),
    /// Placeholder where parsing failed (already reported).
    Error,
}

/// Substance or override.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GraphKind {
    /// `substance name { … }`
    Substance,
    /// `override name { … }`
    Override,
}

/// The four products a substance may bind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Product {
    /// The BSDF closure.
    Surface,
    /// Height along the normal (displacement or bump).
    Displacement,
    /// The shading normal.
    Normal,
    /// Opacity in [0, 1].
    Mask,
    /// Emitted radiance (a colour), one-sided, where the layer is picked (DESIGN.md rule 5).
    Emission,
}

impl Product {
    /// All products in canonical order.
    pub const ALL: [Product; 5] =
        [Product::Surface, Product::Displacement, Product::Normal, Product::Mask, Product::Emission];

    /// The keyword.
    pub fn name(self) -> &'static str {
        match self {
            Product::Surface => "surface",
            Product::Displacement => "displacement",
            Product::Normal => "normal",
            Product::Mask => "mask",
            Product::Emission => "emission",
        }
    }

    /// Parses a product keyword.
    pub fn from_name(name: &str) -> Option<Product> {
        Product::ALL.into_iter().find(|p| p.name() == name)
    }
}

/// A `substance` or `override` declaration.
#[derive(Clone, Debug)]
pub struct GraphDecl {
    /// Which of the two.
    pub kind: GraphKind,
    /// The name scenes refer to (`subIdentifier`).
    pub name: Ident,
    /// Members in source order.
    pub items: Vec<GraphItem>,
    /// The whole declaration.
    pub span: Span,
}

/// A member of a graph declaration.
#[derive(Clone, Debug)]
pub enum GraphItem {
    /// `input type name = literal;` — an exposed, scene-settable input.
    Input {
        /// Its type.
        ty: TypeExpr,
        /// Its name.
        name: Ident,
        /// Its default.
        default: Option<Expr>,
    },
    /// `output type name = value;` — an override output that drives a same-named input.
    Output {
        /// Its type.
        ty: TypeExpr,
        /// Its name.
        name: Ident,
        /// What drives it: a literal, an input or `node.port`.
        value: Expr,
    },
    /// `node name = type(port: value, …);`
    Node {
        /// Instance name.
        name: Ident,
        /// Node type name.
        node_type: Ident,
        /// Port assignments.
        args: Vec<(Ident, Expr)>,
    },
    /// `surface = node.port;` and the like.
    Product {
        /// Which product.
        product: Product,
        /// Where the keyword is.
        span: Span,
        /// What drives it.
        value: Expr,
    },
}
