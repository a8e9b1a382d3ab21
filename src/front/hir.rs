//! The typed, name-resolved form of node-type and function bodies. Every expression carries
//! its type; implicit conversions are explicit [`ExprKind::Convert`] nodes; names are resolved
//! to locals, globals, intrinsics or user functions. Code generation lowers this form; the
//! constant folder evaluates it.

use super::ast::{BaseType, BinaryOp, FunctionKind};
use super::intrinsics::Intrinsic;
use super::types::{Type, Value};
use crate::diag::Span;

/// Index of a local variable (parameters first) within one function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct LocalId(pub u32);

/// Index of a function in a [`crate::front::library::Library`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FuncId(pub u32);

/// Shading globals a body may read. The renderer fills them per shading point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Global {
    /// Shading position.
    P,
    /// Shading normal (after displacement/bump of lower layers).
    N,
    /// Geometric normal.
    Ng,
    /// Incident ray direction (towards the surface).
    I,
    /// Surface parameter / texture coordinate s.
    U,
    /// Surface parameter / texture coordinate t.
    V,
    /// Tangent along u.
    DPdu,
    /// Tangent along v.
    DPdv,
}

impl Global {
    /// Every global, in ABI order.
    pub const ALL: [Global; 8] =
        [Global::P, Global::N, Global::Ng, Global::I, Global::U, Global::V, Global::DPdu, Global::DPdv];

    /// The name used in source.
    pub fn name(self) -> &'static str {
        match self {
            Global::P => "P",
            Global::N => "N",
            Global::Ng => "Ng",
            Global::I => "I",
            Global::U => "u",
            Global::V => "v",
            Global::DPdu => "dPdu",
            Global::DPdv => "dPdv",
        }
    }

    /// Its type.
    pub fn ty(self) -> Type {
        match self {
            Global::P => Type::POINT,
            Global::N | Global::Ng => Type::NORMAL,
            Global::I | Global::DPdu | Global::DPdv => Type::VECTOR,
            Global::U | Global::V => Type::FLOAT,
        }
    }

    /// Looks a global up by its source name.
    pub fn from_name(name: &str) -> Option<Global> {
        Global::ALL.into_iter().find(|g| g.name() == name)
    }
}

/// A local variable or parameter.
#[derive(Clone, Debug)]
pub struct Local {
    /// Its name (for text forms and diagnostics).
    pub name: String,
    /// Its type.
    pub ty: Type,
    /// Where it is declared.
    pub span: Span,
}

/// A parameter of a node type or function.
#[derive(Clone, Debug)]
pub struct Param {
    /// Its name: the port name in graphs.
    pub name: String,
    /// Its type.
    pub ty: Type,
    /// Whether it is an output.
    pub output: bool,
    /// Its default, evaluated in the body's context when the port is not connected.
    pub default: Option<Expr>,
    /// Where it is declared.
    pub span: Span,
}

/// A checked shader (node type) or function.
#[derive(Clone, Debug)]
pub struct Function {
    /// Its name.
    pub name: String,
    /// Shader or function.
    pub kind: FunctionKind,
    /// Parameters; parameter `i` is local `i`.
    pub params: Vec<Param>,
    /// Result type (`void` for shaders).
    pub ret: Type,
    /// All locals, parameters first.
    pub locals: Vec<Local>,
    /// The body.
    pub body: Vec<Stmt>,
    /// Whether the body (or a callee; parameter defaults excluded) reads a shading global or
    /// calls a runtime function with hidden state (texture), so it cannot be folded at compile
    /// time even when every input is constant.
    pub varying: bool,
    /// Where it is declared.
    pub span: Span,
    /// Whether this is part of the built-in library.
    pub builtin: bool,
}

impl Function {
    /// The input ports of a shader, with their parameter indices.
    pub fn inputs(&self) -> impl Iterator<Item = (usize, &Param)> {
        self.params.iter().enumerate().filter(|(_, p)| !p.output)
    }

    /// The output ports of a shader, with their parameter indices.
    pub fn outputs(&self) -> impl Iterator<Item = (usize, &Param)> {
        self.params.iter().enumerate().filter(|(_, p)| p.output)
    }

    /// Finds a parameter by name.
    pub fn param(&self, name: &str) -> Option<(usize, &Param)> {
        self.params.iter().enumerate().find(|(_, p)| p.name == name)
    }
}

/// Where an assignment stores.
#[derive(Clone, Debug)]
pub struct Place {
    /// The variable.
    pub local: LocalId,
    /// Array element, if the variable is an array.
    pub element: Option<Box<Expr>>,
    /// Component of a triple (constant or computed int), if any.
    pub component: Option<Box<Expr>>,
}

/// A checked statement.
#[derive(Clone, Debug)]
pub enum Stmt {
    /// Stores a value (already converted to the place's type).
    Assign(Place, Expr),
    /// Evaluates for effect.
    Eval(Expr),
    /// Two-way branch.
    If(Expr, Vec<Stmt>, Vec<Stmt>),
    /// `while (cond) { body; step }`; `continue` runs `step`.
    Loop {
        /// Checked before each iteration.
        cond: Option<Expr>,
        /// The body.
        body: Vec<Stmt>,
        /// Runs after the body and on `continue`.
        step: Vec<Stmt>,
        /// Where the loop is (for iteration-budget errors).
        span: Span,
    },
    /// Leaves the innermost loop.
    Break,
    /// Next iteration of the innermost loop.
    Continue,
    /// Leaves the function.
    Return(Option<Expr>),
}

/// A checked expression with its type.
#[derive(Debug)]
pub struct Expr {
    /// The computation.
    pub kind: ExprKind,
    /// The result type.
    pub ty: Type,
    /// Where it is written.
    pub span: Span,
}

impl Clone for Expr {
    /// Clones along the left spine in a loop (see [`Expr::left_spine`]); other operands
    /// recurse, as deep as the source may nest.
    fn clone(&self) -> Expr {
        let (spine, leaf) = self.left_spine();
        let mut acc = Expr { kind: leaf.kind.clone(), ty: leaf.ty, span: leaf.span };
        for node in spine.into_iter().rev() {
            let kind = match &node.kind {
                ExprKind::Binary(op, _, b) => ExprKind::Binary(*op, Box::new(acc), b.clone()),
                _ => ExprKind::Convert(Box::new(acc)),
            };
            acc = Expr { kind, ty: node.ty, span: node.span };
        }
        acc
    }
}

impl Drop for Expr {
    /// Drops the tree without recursing per level (a flat chain of 100 000 `+` is a left-deep
    /// tree that deep; the derived drop would recurse once per level).
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
                let leaf = Expr { kind: ExprKind::Const(Value::Int(0)), ty: slot.ty, span: slot.span };
                out.push(std::mem::replace(slot, leaf));
            }
        };
        match self {
            ExprKind::Unary(_, a) | ExprKind::Convert(a) | ExprKind::Component(a, _) => take(a),
            ExprKind::Binary(_, a, b) | ExprKind::Index(a, b) => {
                take(a);
                take(b);
            }
            ExprKind::Select(a, b, c) => {
                take(a);
                take(b);
                take(c);
            }
            ExprKind::Construct(parts) => parts.iter_mut().for_each(take),
            ExprKind::Array(items) | ExprKind::Intrinsic(_, items) | ExprKind::Call(_, items) => {
                items.iter_mut().for_each(take)
            }
            ExprKind::Const(_) | ExprKind::Local(_) | ExprKind::Global(_) => {}
        }
    }

    /// Whether this form has operand expressions.
    pub fn has_operands(&self) -> bool {
        !matches!(self, ExprKind::Const(_) | ExprKind::Local(_) | ExprKind::Global(_))
    }
}

/// Unary operations after checking.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum UnaryOp {
    /// Arithmetic negation (int, float, triple).
    Neg,
    /// Logical not (int result).
    Not,
}

/// The checked expression forms.
#[derive(Clone, Debug)]
pub enum ExprKind {
    /// A constant.
    Const(Value),
    /// Reads a local or parameter.
    Local(LocalId),
    /// Reads a shading global.
    Global(Global),
    /// Unary operation.
    Unary(UnaryOp, Box<Expr>),
    /// Binary operation; operands already converted to a common type, except that
    /// comparisons and logic produce `int`.
    Binary(BinaryOp, Box<Expr>, Box<Expr>),
    /// `cond ? a : b`, only the chosen side is evaluated.
    Select(Box<Expr>, Box<Expr>, Box<Expr>),
    /// Implicit or explicit conversion to `self.ty`.
    Convert(Box<Expr>),
    /// Builds a triple from three floats.
    Construct(Box<[Expr; 3]>),
    /// Reads one component of a triple.
    Component(Box<Expr>, u8),
    /// Reads an array element or a triple component by computed index (bounds-checked).
    Index(Box<Expr>, Box<Expr>),
    /// An array built from elements.
    Array(Vec<Expr>),
    /// A built-in function.
    Intrinsic(Intrinsic, Vec<Expr>),
    /// A user function (inlined by code generation).
    Call(FuncId, Vec<Expr>),
}

impl Expr {
    /// A constant expression.
    pub fn constant(value: Value, ty: Type, span: Span) -> Expr {
        Expr { kind: ExprKind::Const(value), ty, span }
    }

    /// Wraps `self` in a conversion to `to` when its type differs.
    pub fn convert_to(self, to: Type) -> Expr {
        if self.ty == to {
            return self;
        }
        if let ExprKind::Const(value) = &self.kind {
            return Expr::constant(value.convert(self.ty, to), to, self.span);
        }
        let span = self.span;
        Expr { kind: ExprKind::Convert(Box::new(self)), ty: to, span }
    }

    /// The binary operators and conversions along this expression's left operands, outermost
    /// first, and the expression they start from. `x + x + … + x` parses to a left-deep tree
    /// as deep as the chain is long; passes evaluate it from the leaf up, in a loop, instead of
    /// recursing into the left operand once per operator.
    pub fn left_spine(&self) -> (Vec<&Expr>, &Expr) {
        let mut spine = Vec::new();
        let mut leaf = self;
        while let ExprKind::Binary(_, a, _) | ExprKind::Convert(a) = &leaf.kind {
            spine.push(leaf);
            leaf = a;
        }
        (spine, leaf)
    }

    /// The constant value, if this is a constant.
    pub fn as_const(&self) -> Option<&Value> {
        match &self.kind {
            ExprKind::Const(v) => Some(v),
            _ => None,
        }
    }
}

/// The triple type constructed by a constructor name, if any.
pub fn triple_constructor(name: &str) -> Option<BaseType> {
    match name {
        "color" => Some(BaseType::Color),
        "point" => Some(BaseType::Point),
        "vector" => Some(BaseType::Vector),
        "normal" => Some(BaseType::Normal),
        _ => None,
    }
}
