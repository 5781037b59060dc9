#!/usr/bin/env bash
# Adapts the kernel's own sources to an out-of-tree build inside one module.
# Runs in the build directory. Fails when an edit no longer applies, so that a
# new kernel series is noticed here rather than as a broken module.
set -euo pipefail

mv gpio-sim.c gpio-sim-driver.c

# The interrupt simulator is private to this module: no exports, which would
# clash with a kernel that has CONFIG_IRQ_SIM after all.
grep -q '^EXPORT_SYMBOL' irq_sim.c
sed -i '/^EXPORT_SYMBOL/d' irq_sim.c

# irq_to_desc() is not exported to modules; generic_handle_irq() does the same
# lookup and calls the handler that irq_sim installed (handle_simple_irq).
grep -q 'handle_simple_irq(irq_to_desc(irqnum));' irq_sim.c
sed -i 's/handle_simple_irq(irq_to_desc(irqnum));/generic_handle_irq(irqnum);/' irq_sim.c
