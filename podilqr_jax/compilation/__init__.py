"""How the solver's programs are compiled, apart from what they compute: the stages kept on disk as
traced programs (``stages``), the solves of ``restarts`` batched stage by stage (``lockstep``), JAX's
persistent compilation cache (``cache``), XLA's options (``xla_options``) and the compile log
(``compile_watch``). It imports nothing of the solver's own: everything else imports it."""
