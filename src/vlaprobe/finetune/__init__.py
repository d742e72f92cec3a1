"""``vlaprobe finetune``: behaviour cloning of OpenVLA models with OpenVLA's own fine-tuning objective.

:mod:`data` reads the demonstrations from collection stores and splits them by episode; :mod:`objective`
builds the teacher-forced sequences and computes the logits at the 8 labelled positions only;
:mod:`loop` trains (AdamW, warm-up + cosine, clipping) and checkpoints through :mod:`state`;
:mod:`lora` adds peft adapters for large checkpoints; :mod:`command` ties them to the CLI.
"""
